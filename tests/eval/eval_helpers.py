"""Small benchmark folders written by the tests in each dataset's exact layout."""

from __future__ import annotations

import csv
import json
import subprocess
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image

from ravenmem.eval.config import (
    DatasetConfig,
    MemoryConfig,
    MethodConfig,
    ModelConfig,
    OutputConfig,
    RunConfig,
    Thresholds,
)
from tests.cli.helpers import run_cli

REPO = Path(__file__).resolve().parents[2]
COLORS = {
    "red": (230, 20, 20),
    "green": (20, 200, 20),
    "blue": (20, 20, 230),
    "yellow": (230, 230, 20),
    "cyan": (20, 230, 230),
    "magenta": (230, 20, 230),
    "white": (240, 240, 240),
    "black": (5, 5, 5),
    "grey": (120, 120, 120),
}


def solid(color: str, h: int = 24, w: int = 32) -> np.ndarray:
    img = np.zeros((h, w, 3), dtype=np.uint8)
    img[:] = COLORS[color]
    return img


def save(path: Path, img: np.ndarray) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(img).save(path, quality=95)


class CountingColorEmbedder:
    """Colour embedder (mean colour direction; texts -> the colour they name) that counts images."""

    name = "test-color-eval"
    dim = 4

    def __init__(self) -> None:
        self.images = 0

    def embed_images(self, images: Sequence[np.ndarray]) -> np.ndarray:
        self.images += len(images)
        out = [list(im.reshape(-1, 3).astype(np.float32).mean(0) / 255.0) + [0.1] for im in images]
        v = np.asarray(out, dtype=np.float32).reshape(-1, 4)
        return v / np.linalg.norm(v, axis=1, keepdims=True)

    def embed_texts(self, texts: Sequence[str]) -> np.ndarray:
        out = []
        for t in texts:
            c = next((COLORS[w] for w in t.lower().replace("?", " ").split() if w in COLORS), (0, 0, 0))
            out.append([c[0] / 255, c[1] / 255, c[2] / 255, 0.1])
        v = np.asarray(out, dtype=np.float32)
        return v / np.linalg.norm(v, axis=1, keepdims=True)


def color_embedder(spec: str = "", **_: Any) -> CountingColorEmbedder:
    """The embedder factory a plugin registers (entry point `ravenmem.embedders`: test-color-eval)."""
    return CountingColorEmbedder()


@pytest.fixture
def embedder() -> CountingColorEmbedder:
    return CountingColorEmbedder()


def run_cfg(
    dataset: str,
    methods: list[str],
    tmp: Path,
    *,
    out: str = "run",
    method_opts: dict[str, Any] | None = None,
    dataset_opts: dict[str, Any] | None = None,
    thresholds: Thresholds | None = None,
    keyframes: str | None = None,
    embedder: str = "offline",
    vlm: str | None = None,
    vlm_base_url: str | None = None,
    judge: str | None = None,
    judge_base_url: str | None = None,
    **run: Any,
) -> RunConfig:
    """A RunConfig for tests: cache and run folder under `tmp`, small thumbnails, no progress bar."""
    return RunConfig(
        dataset=DatasetConfig(dataset, **(dataset_opts or {})),
        methods=MethodConfig(methods, **(method_opts or {})),
        models=ModelConfig(
            embedder=embedder, vlm=vlm, vlm_base_url=vlm_base_url, judge=judge, judge_base_url=judge_base_url
        ),
        memory=MemoryConfig(keyframes=keyframes, thumb_size=32, cache_dir=str(tmp / "cache")),
        thresholds=thresholds or Thresholds(),
        output=OutputConfig(out=str(tmp / out)),
        **({"progress": False, "workers": 2} | run),
    )


def plugin_site(tmp: Path) -> Path:
    """A folder that, on PYTHONPATH, installs the test colour embedder the way a third-party
    package does: a dist-info with an entry point in the `ravenmem.embedders` group."""
    site = tmp / "site"
    dist = site / "ravenmem_test_colors-0.1.dist-info"
    dist.mkdir(parents=True, exist_ok=True)
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: ravenmem-test-colors\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text(
        "[ravenmem.embedders]\ntest-color-eval = tests.eval.eval_helpers:color_embedder\n"
    )
    return site


def rm(
    *args: str, site: Path | None = None, env: dict[str, str] | None = None
) -> subprocess.CompletedProcess[str]:
    """The `ravenmem` command in a subprocess (this checkout's code; the plugin site when given)."""
    return run_cli(*args, env=env, timeout=600, paths=(site,) if site else ())


def no_vlm_env(tmp: Path) -> dict[str, str]:
    """An environment with no VLM configured anywhere (no variables, an empty config file)."""
    cfg = tmp / "no-vlm.toml"
    cfg.write_text("")
    env = {
        k: ""
        for k in ("RAVENMEM_VLM_MODEL", "RAVENMEM_VLM_BASE_URL", "RAVENMEM_VLM_API_KEY", "OPENAI_API_KEY")
    }
    return env | {"RAVENMEM_CONFIG": str(cfg)}


RAVEN_COLORS = ["red", "red", "green", "green", "blue", "blue", "yellow", "yellow", "white", "black"]


def write_raven_video(vdir: Path, questions: list[list[Any]] | None = None, **extra: Any) -> Path:
    """A RAVEN-QA video folder: 10 frames walking along x (1 m apart), a colour per pair of frames."""
    for i, c in enumerate(RAVEN_COLORS):
        save(vdir / "frames" / f"frame_{i + 1:03d}.jpg", solid(c))
    qs = (
        questions
        if questions is not None
        else [
            ["Where did you see the blue wall?", "frame_005.jpg", "dominant", None],
            ["Where is the green box?", [[2.0, 0.0, 0.0], "frame_003.jpg"], "secondary", None],
            ["Where was something yellow?", [[6.0, 0.0, 0.0], [7.0, 0.0, 0.0]], "spatial", None],
            [
                "Where was the red thing?",
                [[[0.0, 0.0, 0.0], "frame_001.jpg"], [[1.0, 0.0, 0.0], "frame_002.jpg"]],
                "information recall",
                None,
            ],
        ]
    )
    doc = {
        "questions (ques, answer_in_filename, category, query_img)": qs,
        "timestamp_to_filename": {"00:10:00": "frame_001.jpg", "00:10:18": "frame_010.jpg"},
        "filename_to_position": {f"frame_{i + 1:03d}.jpg": [float(i), 0.0, 0.0] for i in range(10)},
    } | extra
    (vdir / "questions.json").write_text(json.dumps(doc), encoding="utf-8")
    return vdir


# Target frames of the scoring fixture: 40 grey frames 3 m apart, one coloured frame per object,
# so that an answer picked at random names the right frame (or lands within 2 m) 1 time in 40.
TARGETS = {"cyan": 2, "red": 5, "green": 13, "blue": 22, "yellow": 31, "magenta": 37}
QUESTIONS = {
    "simple": [
        ("Where did you see the red door?", "red", "dominant"),
        ("Where is the green box?", "green", "secondary"),
        ("Where was the blue chair?", "blue", "spatial"),
    ],
    "hard": [
        ("Where did I last see something yellow?", "yellow", "reasoning"),
        ("Where is the magenta cup?", "magenta", "information recall"),
        ("Which place had the cyan poster?", "cyan", "spatial"),
    ],
}


def write_scoring_video(vdir: Path, split: str, n: int = 40) -> Path:
    """A RAVEN-QA video on which random answers fail: n frames along x, 3 m apart, 1 s apart."""
    for i in range(n):
        colour = next((c for c, j in TARGETS.items() if j == i), "grey")
        save(vdir / "frames" / f"frame_{i + 1:03d}.jpg", solid(colour))
    rows = []
    for k, (text, colour, category) in enumerate(QUESTIONS[split]):
        fname = f"frame_{TARGETS[colour] + 1:03d}.jpg"
        # answer forms: a file; a position with its file; a file (position from filename_to_position)
        answer: Any = [[3.0 * TARGETS[colour], 0.0, 0.0], fname] if k == 1 else fname
        rows.append([text, answer, category, None])
    doc = {
        "questions (ques, answer_in_filename, category, query_img)": rows,
        "timestamp_to_filename": {"01:00:00": "frame_001.jpg", f"01:00:{n - 1:02d}": f"frame_{n:03d}.jpg"},
        "filename_to_position": {f"frame_{i + 1:03d}.jpg": [3.0 * i, 0.0, 0.0] for i in range(n)},
    }
    vdir.mkdir(parents=True, exist_ok=True)
    (vdir / "questions.json").write_text(json.dumps(doc), encoding="utf-8")
    return vdir


def write_scoring_dataset(root: Path) -> Path:
    """Two subsets (sim, real_world) x simple/hard splits: 3 videos, 9 questions."""
    write_scoring_video(root / "sim" / "simple" / "ep_a", "simple")
    write_scoring_video(root / "sim" / "hard" / "ep_b", "hard")
    write_scoring_video(root / "real_world" / "hard" / "vid_c", "hard")
    return root


@pytest.fixture
def scoring_root(tmp_path: Path) -> Path:
    return write_scoring_dataset(tmp_path / "RAVEN_QA")


@pytest.fixture
def raven_root(tmp_path: Path) -> Path:
    root = tmp_path / "RAVEN_QA" / "real_world"
    write_raven_video(root / "vid_a")
    return root


NAVQA_HEADER = [
    "UUID",
    "Seq ID",
    "Question",
    "Timestamp \nwith answer",
    "Type \n(binary, position, time, text)",
    "Text answer",
    "Parsable answer",
    "Question\nCategory",
]
T0 = 1673884500.0  # 2023-01-16 09:55:00 America/Chicago


def write_navqa(root: Path, with_human_qa: bool = True) -> Path:
    """Sequence 0: 20 frames at 1 Hz moving along y (2 m/s), colours in blocks of 5."""
    seq = root / "frames" / "0"
    rows = []
    colors = ["red"] * 5 + ["green"] * 5 + ["blue"] * 5 + ["yellow"] * 5
    for i, c in enumerate(colors):
        save(seq / f"{i:04d}.png", solid(c))
        rows.append([f"{i:04d}.png", f"{T0 + i:.3f}", "0.0", f"{2.0 * i:.3f}", "0.0"])
    with open(seq / "poses.csv", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["file", "t", "x", "y", "z"])
        w.writerows(rows)
    table = [
        ["SHORT_a", "0", "Where is the blue door?", "9:55:11", "position", "", "[position]", "spatial"],
        [
            "SHORT_b",
            "0",
            "When did you see the green wall?",
            "9:55:06",
            "time",
            "",
            "[minutes] ago",
            "temporal",
        ],
        ["LONG_c", "0", "Did you see a yellow car?", "9:55:16", "binary", "", "yes", "environmental"],
        [
            "LONG_d",
            "0",
            "How long were you near green things?",
            "9:55:05,9:55:09",
            "duration",
            "about 4 s",
            "0.0667",
            "temporal reasoning",
        ],
        [
            "LONG_e",
            "0",
            "What colour was the wall at the start?",
            "9:55:01",
            "text",
            "It was red",
            "",
            "descriptive",
        ],
    ]
    with open(root / "data.csv", "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(NAVQA_HEADER)
        w.writerows(table)
    if with_human_qa:
        items = [
            {
                "id": "SHORT_a",
                "length_category": "SHORT",
                "start_time": T0 + 5,
                "end_time": T0 + 15,
                "question": "You started moving at X.\n Where is the blue door?",
                "type": "position",
                "answers": {"position": [0.0, 22.0, 0.0]},
            },
            {
                "id": "SHORT_b",
                "length_category": "SHORT",
                "start_time": T0 + 5,
                "end_time": T0 + 15,
                "question": "When did you see the green wall?",
                "type": "time",
                "answers": {"text": ["0.15 minutes ago"], "time": 0.15},
            },
            {
                "id": "LONG_c",
                "length_category": "LONG",
                "start_time": T0,
                "end_time": T0 + 19,
                "question": "Did you see a yellow car?",
                "type": "binary",
                "answers": {"text": ["yes", "yes"]},
            },
            {
                "id": "LONG_d",
                "length_category": "LONG",
                "start_time": T0,
                "end_time": T0 + 19,
                "question": "How long?",
                "type": "duration",
                "answers": {"text": ["0.0667 minutes"], "duration": 0.0667},
            },
            {
                "id": "LONG_e",
                "length_category": "LONG",
                "start_time": T0,
                "end_time": T0 + 19,
                "question": "What colour?",
                "type": "text",
                "answers": {"text": ["It was red"]},
            },
        ]
        qdir = root / "questions" / "0"
        qdir.mkdir(parents=True)
        (qdir / "human_qa.json").write_text(json.dumps({"version": 0.1, "data": items}), encoding="utf-8")
    return root


def write_video(path: Path, colors: list[str], fps: int = 5) -> Path:
    import av

    path.parent.mkdir(parents=True, exist_ok=True)
    with av.open(str(path), "w") as c:
        st = c.add_stream("mpeg4", rate=fps)
        st.width, st.height, st.pix_fmt = 32, 32, "yuv420p"
        for col in colors:
            fr = av.VideoFrame.from_ndarray(solid(col, 32, 32), format="rgb24")
            for pkt in st.encode(fr):
                c.mux(pkt)
        for pkt in st.encode():
            c.mux(pkt)
    return path


def write_findingdory(root: Path, fmt: str = "jsonl") -> Path:
    write_video(root / "videos" / "validation" / "ep_id_7.mp4", ["red"] * 4 + ["green"] * 4 + ["blue"] * 4)
    rows = [
        {
            "ep_id": "7",
            "video": "videos/validation/ep_id_7.mp4",
            "question": "Which frame shows the green box?",
            "answer": "[[4, 5, 6, 7]]",
            "task_id": "t1",
            "high_level_category": "Single-Goal Spatial Tasks",
            "low_level_category": "object recall",
            "num_interactions": 3,
        },
        {
            "ep_id": "7",
            "video": "videos/validation/ep_id_7.mp4",
            "question": "Red, then blue?",
            "answer": "[[0, 1], [9, 10, 11]]",
            "task_id": "t2",
            "high_level_category": "Multi-Goal Tasks",
            "low_level_category": "sequence",
            "num_interactions": 3,
        },
        {
            "ep_id": "7",
            "video": "videos/validation/ep_id_7.mp4",
            "question": "Where is the purple sofa?",
            "answer": "[[-1]]",
            "task_id": "t3",
            "high_level_category": "Single-Goal Spatial Tasks",
            "low_level_category": "negative",
            "num_interactions": 3,
        },
    ]
    if fmt == "jsonl":
        (root / "validation.jsonl").write_text("\n".join(json.dumps(r) for r in rows) + "\n")
    else:
        import pyarrow as pa
        import pyarrow.parquet as pq

        (root / "data").mkdir(parents=True, exist_ok=True)
        pq.write_table(pa.Table.from_pylist(rows), root / "data" / "validation-00000-of-00001.parquet")
    return root
