"""FindingDory: Habitat episodes as videos, questions answered with frame indices.

Layout (`findingdory:PATH`, the Hugging Face dataset folder):

    PATH/data/validation-*.parquet       the validation rows (needs pyarrow), or any of
    PATH/validation.jsonl | .json | .csv  the same rows exported
    PATH/<video>                          each row's `video`, e.g. videos/validation/ep_id_1157.mp4

Row fields: ep_id, video, question, answer (a JSON list of lists: per goal, the acceptable frame
indices; `[[-1]]` means no frame answers it), task_id, high_level_category, low_level_category.

Frame i of a video is at in-game time 06:00 + i / 4.168 minutes (the benchmark records 4.168
frames per in-game minute); memories get that time of day on 2000-01-01 UTC, so questions that
name in-game times ("between 08:00 and 10:00") resolve against the memory's own clock. Videos
carry no poses: frames are stored at the origin and only frame answers are scored.

Questions get the normalisations the RAVEN release applies before asking: the "The robot's goal
is: " prefix is dropped and clock times written H:MM become HH:MM:SS. Multi-goal answers name
one place per goal in order, in any form a release's prompt asks for (`eval.answer_forms`:
FindingDory's frame_indices, RAVEN's space-separated "time", our "Goal times:" line); the methods
that ask a model are told to list every goal's time as "Goal times: HH:MM:SS HH:MM:SS"
(`INSTRUCTIONS`), and each goal is scored against its own accepted frames, in order
(the scorer's rule: a goal is right when its time, rounded to the nearest frame, is one of them;
all goals right for the answer to be right; `[[-1]]` right only when nothing is found).
"""

from __future__ import annotations

import csv
import json
import re
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ...errors import InputError, require
from ...fsio import read_text
from ...types import Pose
from ..types import Episode, Question, Truth, horizon_of
from . import DATASETS
from .frames import BASE_DAY, VideoSource, natural_key, video_frame_count

FRAMES_PER_MINUTE = 4.168
START_S = 6 * 3600.0  # 06:00 in-game
TIME_RULE = f"frame i at in-game time 06:00 + i / {FRAMES_PER_MINUTE} min (frame = round((t - 06:00) x {FRAMES_PER_MINUTE}/min))"
GOAL_PREFIX = "The robot's goal is: "
_CLOCK = re.compile(r"(?<![\d:])([01]?\d|2[0-3]):([0-5]\d)(?![\d:])")  # H:MM, not HH:MM:SS
INSTRUCTIONS = (
    "Answer with the time of each goal the instruction names, in the order it names them: end your "
    'answer text with "Goal times: HH:MM:SS HH:MM:SS ..." (one time for a single goal), and put '
    'the first goal\'s time in "time".'
)


def normalise_question(text: str) -> str:
    """The release's question normalisations: no "The robot's goal is: " prefix, and H:MM clock
    times as HH:MM:00."""
    text = text.replace(GOAL_PREFIX, "")
    return _CLOCK.sub(lambda m: f"{int(m.group(1)):02d}:{int(m.group(2)):02d}:00", text).strip()


def frame_time(i: int) -> float:
    """Unix seconds of frame i (in-game time of day on the base day)."""
    return BASE_DAY + START_S + i * 60.0 / FRAMES_PER_MINUTE


def frame_of_time(t: float) -> int:
    return max(0, round((t - BASE_DAY - START_S) * FRAMES_PER_MINUTE / 60.0))


def read_rows(root: Path, split: str) -> tuple[list[dict[str, Any]], Path]:
    """The split's rows from parquet / jsonl / json / csv, and the file they came from."""
    parquet = sorted((root / "data").glob(f"{split}-*.parquet")) + sorted(root.glob(f"{split}*.parquet"))
    if parquet:
        pq: Any = require("pyarrow.parquet", "eval")
        rows: list[dict[str, Any]] = []
        for p in parquet:
            rows += pq.read_table(p).to_pylist()
        return rows, parquet[0]
    for ext in ("jsonl", "json", "csv"):
        p = root / f"{split}.{ext}"
        if not p.exists():
            continue
        try:
            if ext == "jsonl":
                out = []
                for n, line in enumerate(read_text(p, what="question file").splitlines(), start=1):
                    if line.strip():
                        try:
                            out.append(json.loads(line))
                        except json.JSONDecodeError as e:
                            raise InputError(f"{p} line {n}: not JSON ({e.msg})") from None
                return out, p
            if ext == "json":
                data = json.loads(read_text(p, what="question file"))
                return (data if isinstance(data, list) else data.get("data", [])), p
            with open(p, newline="", encoding="utf-8") as f:
                return list(csv.DictReader(f)), p
        except (OSError, ValueError) as e:  # ValueError: not UTF-8, not JSON
            raise InputError(f"{p}: cannot read ({e})") from e
    raise InputError(f"{root}: no {split} rows (expected data/{split}-*.parquet or {split}.jsonl/.json/.csv)")


def parse_answer(text: Any, where: str) -> list[list[int]]:
    """'[[12, 13], [40]]' -> per-goal lists of acceptable frame indices."""
    try:
        val = json.loads(text) if isinstance(text, str) else text
    except json.JSONDecodeError:
        raise InputError(f"{where}: answer {text!r} is not a JSON list of lists") from None
    if isinstance(val, list) and val and all(isinstance(v, int) for v in val):
        val = [val]
    if not (
        isinstance(val, list)
        and val
        and all(isinstance(g, list) and g and all(isinstance(i, int) for i in g) for g in val)
    ):
        raise InputError(f"{where}: answer {text!r} is not a list of lists of frame indices")
    return [list(g) for g in val]


def _origin(i: int) -> Pose:
    return Pose(0.0, 0.0, 0.0)


def _video(name: str, path: Path) -> Callable[[], VideoSource]:
    return lambda: VideoSource(name, path, frame_time, _origin)


def load(path: str, split: str = "validation", **_: Any) -> list[Episode]:
    """One episode per video; its questions are the rows that point at it."""
    root = Path(path)
    if not root.is_dir():
        raise InputError(f"FindingDory folder {root} does not exist")
    rows, src = read_rows(root, split)
    by_video: dict[str, list[tuple[int, dict[str, Any]]]] = {}
    for n, row in enumerate(rows):
        for k in ("video", "question", "answer"):
            if not row.get(k):
                raise InputError(f"{src} row {n}: missing {k!r}")
        by_video.setdefault(str(row["video"]), []).append((n, row))
    episodes = []
    for video, items in sorted(by_video.items(), key=lambda kv: natural_key(kv[0])):
        vpath = root / video
        if not vpath.is_file():
            raise InputError(f"{src}: video {video!r} not found at {vpath}")
        n_frames = video_frame_count(vpath)
        times = [frame_time(i) for i in range(n_frames)]
        name = f"findingdory/{Path(video).stem}"
        qs = []
        for n, row in items:
            where = f"{src} row {n}"
            goals = parse_answer(row["answer"], where)
            none = goals == [[-1]]
            truth = Truth(frames=[] if none else goals, none=none)
            qid = f"{row.get('ep_id', Path(video).stem)}:{row.get('task_id', n)}:{n}"
            qs.append(
                Question(
                    id=qid,
                    text=normalise_question(str(row["question"])),
                    type="frame",
                    truth=truth,
                    instructions=INSTRUCTIONS,
                    category=str(row.get("high_level_category") or "").lower(),
                    horizon=horizon_of(times[-1] - times[0] if n_frames > 1 else None),
                    meta={
                        # the episode: the release's long-range subset is episodes ep_91-ep_100
                        "ep_id": str(row.get("ep_id") or Path(video).stem),
                        "low_level_category": row.get("low_level_category"),
                        "task_id": row.get("task_id"),
                        "goals": len(goals),
                    },
                )
            )
        episodes.append(
            Episode(
                id=name,
                dataset="findingdory",
                key=f"findingdory:{vpath.resolve()}",
                questions=qs,
                frames=_video(name, vpath),
                frame_times=times,
                has_poses=False,
                frame_tol=0.5 * 60.0 / FRAMES_PER_MINUTE,
                meta={"video": video, "frames": n_frames, "time_rule": TIME_RULE},
            )
        )
    return episodes


DATASETS.register("findingdory")(load)
