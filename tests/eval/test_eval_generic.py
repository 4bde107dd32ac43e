from __future__ import annotations

import json
from pathlib import Path

import pytest

from ravenmem.errors import InputError
from ravenmem.eval.datasets import load_dataset
from ravenmem.eval.runner import Runner, read_rows
from tests.conftest import tum_data
from tests.eval.eval_helpers import CountingColorEmbedder, run_cfg, save, solid

REPO = Path(__file__).resolve().parents[2]
T0 = 1305031229.5


def write_tum(root: Path) -> Path:
    """A TUM RGB-D style folder: 12 frames at 10 Hz, a pose track at 100 Hz moving along x."""
    colors = ["red"] * 4 + ["green"] * 4 + ["blue"] * 4
    rgb = ["# color images", "# timestamp filename"]
    for i, c in enumerate(colors):
        name = f"rgb/{T0 + 0.1 * i:.6f}.png"
        save(root / name, solid(c))
        rgb.append(f"{T0 + 0.1 * i:.6f} {name}")
    (root / "rgb.txt").write_text("\n".join(rgb) + "\n")
    gt = ["# timestamp tx ty tz qx qy qz qw"]
    gt += [f"{T0 - 0.05 + 0.01 * k:.4f} {0.01 * k:.4f} 0 1 0 0 0 1" for k in range(130)]
    (root / "groundtruth.txt").write_text("\n".join(gt) + "\n")
    return root


def name(i: int) -> str:
    return f"rgb/{T0 + 0.1 * i:.6f}.png"


def test_questions_file_over_a_tum_folder(tmp_path: Path, embedder: CountingColorEmbedder) -> None:
    rec = write_tum(tmp_path / "tum")
    q = {
        "time_tolerance_s": 0.2,
        "questions": [
            {
                "id": "green",
                "question": "When did you see green?",
                "type": "frame",
                "answer": {"frame_ranges": [[name(4), name(7)]]},
            },
            {
                "id": "blue-where",
                "question": "Where was the blue wall?",
                "type": "position",
                "answer": {"frames": [name(9)], "tolerance_m": 0.25},
            },
            {
                "id": "red-when",
                "question": "When did you see red?",
                "type": "time",
                "answer": {"window": [0.0, 0.35]},
            },
            {"id": "t", "question": "When did you start?", "type": "time", "answer": {"time": 0.0}},
            {"id": "b", "question": "Did you see a blue wall?", "type": "binary", "answer": {"yes": True}},
            {"id": "x", "question": "What colour?", "type": "text", "answer": {"text": "red"}},
        ],
    }
    qfile = tmp_path / "q.json"
    qfile.write_text(json.dumps(q))
    (ep,) = load_dataset(f"tum:{rec}", queries=str(qfile))
    qs = {x.id: x for x in ep.questions}
    assert qs["green"].truth.files == [name(i) for i in range(4, 8)]
    assert qs["green"].truth.times[0] == pytest.approx(T0 + 0.4)
    assert qs["blue-where"].truth.positions[0][0] == pytest.approx(0.1 * 9 + 0.05, abs=1e-6)
    assert ep.t0 == pytest.approx(T0) and len(ep.frame_files) == 12
    cfg = run_cfg(f"tum:{rec}", ["embedder-only"], tmp_path, dataset_opts={"queries": str(qfile)})
    s = Runner(cfg, embedder=embedder, log=lambda _: None).run()
    rows = {r["qid"]: r for r in read_rows(tmp_path / "run")}
    assert rows["green"]["score"]["correct"] and rows["green"]["pred"]["files"][0] in qs["green"].truth.files
    assert rows["red-when"]["truth"]["window"] == pytest.approx([T0, T0 + 0.35])  # resolved from the start
    assert rows["red-when"]["score"]["correct"]
    assert rows["blue-where"]["score"]["correct"]
    assert rows["x"]["score"]["correct"] is None
    assert s["groups"][0]["by"]["type"]["frame"]["accuracy"]["mean"] == 1.0


def test_questions_file_errors(tmp_path: Path) -> None:
    rec = write_tum(tmp_path / "tum")
    bad = [
        ({"question": "Where?", "type": "place", "answer": {}}, "type 'place'"),
        ({"question": "Where?", "type": "position", "answer": {"yes": True}}, "needs an answer of its kind"),
        (
            {"question": "When?", "type": "frame", "answer": {"frames": ["rgb/nope.png"]}},
            "not in .* frame index",
        ),
        (
            {"question": "When?", "type": "frame", "answer": {"frame_ranges": [[name(5), name(1)]]}},
            "backwards",
        ),
    ]
    for item, msg in bad:
        qfile = tmp_path / "q.json"
        qfile.write_text(json.dumps({"questions": [item]}))
        with pytest.raises(InputError, match=f"q.json question 0: .*{msg}"):
            load_dataset(f"tum:{rec}", queries=str(qfile))
    with pytest.raises(InputError, match="needs --queries"):
        load_dataset(f"tum:{rec}")


@pytest.fixture
def tum_real() -> Path:
    return tum_data()


def test_example_tum_queries_against_real_frames(
    tum_real: Path, tmp_path: Path, embedder: CountingColorEmbedder
) -> None:
    qfile = REPO / "benchmarks" / "data" / "tum_queries.json"
    (ep,) = load_dataset(f"queries:{qfile}")
    assert ep.dataset == "tum" and len(ep.frame_files) == 723 and len(ep.questions) == 11
    qs = {q.id: q for q in ep.questions}
    assert len(qs["controller"].truth.files) == 19 + 17 + 15 + 37 + 29 + 17
    assert qs["first-person"].truth.times == [pytest.approx(1305031234.461690)]
    # a quick end-to-end pass over the real recording (every 24th frame, colour embedder)
    cfg = run_cfg(
        f"queries:{qfile}", ["embedder-only"], tmp_path, dataset_opts={"limit": 3}, keyframes="stride=24"
    )
    Runner(cfg, embedder=embedder, log=lambda _: None).run()
    rows = read_rows(tmp_path / "run")
    assert len(rows) == 3 and 25 <= rows[0]["memory"]["memories"] <= 31 and rows[0]["memory"]["frames"] == 723
