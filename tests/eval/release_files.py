"""NaVQA and FindingDory folders written file for file as the public releases ship them, from the
releases' documentation and data files (read with the search tools; nothing is copied):

- data.csv: the header both releases ship (multi-line quoted cells, "Timestamp \\nwith answer"),
  question ids `<LENGTH>_<uuid4>`, answers as unpadded wall-clock times ("7:59:00") in the
  writer's zone, a duration as "07:56:38,07:59:00"; the ReMEmbR copy (remembr/data/navqa/)
  writes the same instant three hours earlier than the RAVEN copy (data_vlm/navqa/).
- <seq>/qa_unfilled.json: {"version": 0.1, "data": [{id, length_category ("LONG"), length,
  start_time, end_time (Unix s), file_info: {qa_start_filename, qa_end_filename}}]}.
- coda_data/<seq>/<pose_ts>.pkl: what the releases' preprocess_coda.py pickles: cam0 (BGR),
  bbox_3d, position, rotation (x, y, z, w), timestamp (numpy float64), named by str(pose_ts).
  ReMEmbR keeps coda_data/ beside data/ in its package folder (eval.md: `--coda_dir
  ./coda_data`, `--data_dir ./data/`); RAVEN at the repository root beside data_vlm/.
- FindingDory (huggingface yali30/findingdory): data/validation-*.parquet rows with ep_id, video
  ("videos/val/ep_1.mp4"), question, answer (a JSON string of per-goal frame lists), task_id,
  high_level_category, low_level_category, num_interactions.
"""

from __future__ import annotations

import csv
import json
import pickle
import uuid
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

import numpy as np

from tests.agent.scripted_server import answer
from tests.eval.eval_helpers import solid, write_video
from tests.eval.release_layouts import question_of

HEADER = [
    "UUID",
    "Seq ID",
    "Question",
    "Timestamp \nwith answer",
    "Type \n(binary, position, time, text)",
    "Text answer",
    "Parsable answer",
    "Question\nCategory",
]
SEQ = "0"
START = 1673884316.1515949  # CODa sequence 0's first clip start in the releases (2023-01-16 15:51:56 UTC)
STEP = 1.4987  # seconds between pose stamps (irregular fractions, as CODa's are)
N_FRAMES = 60
COLOURS = ["red"] * 20 + ["green"] * 20 + ["blue"] * 20
REMEMBR_H, RAVEN_H = -8, -5  # the zones the two published data.csv files are written in


def frame_ts(i: int) -> np.float64:
    return np.float64(round(START + i * STEP, 6))


def _uid(length: str, k: int) -> str:
    return f"{length}_{uuid.uuid5(uuid.NAMESPACE_URL, f'ravenmem-test/navqa/{k}')}"


# (length category, type, question, clip (first, last frame), truth frames, parsable, text answer)
QUESTIONS = [
    ("SHORT", "position", "Where is the blue wall?", (35, 59), [50], "[position]", ""),
    ("SHORT", "binary", "Did you see a purple car?", (0, 30), [12], "no", ""),
    ("MEDIUM", "time", "When did you see the green wall?", (0, 59), [30], "[minutes] ago", ""),
    (
        "LONG",
        "duration",
        "How long did you see green walls?",
        (5, 59),
        [20, 39],
        "0.5",
        "about half a minute",
    ),
    ("LONG", "time", "When did you leave the red hall?", (0, 45), [19], "[minutes] ago", ""),
    ("MEDIUM", "position", "Where is the green door?", (10, 59), [25], "[position]", ""),
]
SLIP = ("MEDIUM", "position", "Where is the red bench?", (30, 59), [5], "[position]", "")  # outside its clip


def ids(questions: list[tuple[Any, ...]]) -> list[str]:
    return [_uid(q[0], k) for k, q in enumerate(questions)]


def clock(t: float, offset_h: int, padded: bool = False) -> str:
    d = datetime.fromtimestamp(t, timezone(timedelta(hours=offset_h)))
    return (
        f"{d.hour:02d}:{d.minute:02d}:{d.second:02d}" if padded else f"{d.hour}:{d.minute:02d}:{d.second:02d}"
    )


def write_data_csv(path: Path, offset_h: int, questions: list[tuple[Any, ...]]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(HEADER)
        for qid, (_, qtype, text, _, truth, parsable, answer) in zip(ids(questions), questions):
            stamps = [float(frame_ts(i)) for i in truth]
            stamp = (
                ",".join(clock(t, offset_h, padded=True) for t in stamps)
                if len(stamps) > 1
                else clock(stamps[0], offset_h)
            )
            w.writerow([qid, SEQ, text, stamp, qtype, answer, parsable, "spatial"])


def write_qa_unfilled(path: Path, questions: list[tuple[Any, ...]]) -> None:
    items = []
    for qid, (length, *_, clip, _t, _p, _a) in zip(ids(questions), questions):
        t0, t1 = float(frame_ts(clip[0])), float(frame_ts(clip[1]))
        items.append(
            {
                "id": qid,
                "length_category": length,
                "length": t1 - t0,
                "start_time": t0,
                "end_time": t1,
                "file_info": {
                    "qa_start_filename": f"{frame_ts(clip[0])}.pkl",
                    "qa_end_filename": f"{frame_ts(clip[1])}.pkl",
                },
            }
        )
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps({"version": 0.1, "data": items}, indent=4), encoding="utf-8")


def write_coda_frames(folder: Path) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for i in range(N_FRAMES):
        ts = frame_ts(i)
        d = {
            "cam0": np.ascontiguousarray(solid(COLOURS[i], 16, 16)[..., ::-1]),
            "bbox_3d": {},
            "position": np.array([float(i), 2.0, 0.0]),
            "rotation": np.array([0.0, 0.0, 0.0, 1.0]),
            "timestamp": ts,
        }
        with open(folder / f"{ts}.pkl", "wb") as f:
            pickle.dump(d, f, protocol=pickle.HIGHEST_PROTOCOL)


def write_remembr_release(repo: Path, slip: bool = True) -> Path:
    """The ReMEmbR repository: remembr/data/navqa/{data.csv, 0/qa_unfilled.json} (UTC-8 clock
    times) and the preprocessed frames in remembr/coda_data/0 (beside data/). Returns the
    package folder (the one its scripts run from)."""
    qs = QUESTIONS + ([SLIP] if slip else [])
    pkg = repo / "remembr"
    write_data_csv(pkg / "data" / "navqa" / "data.csv", REMEMBR_H, qs)
    write_qa_unfilled(pkg / "data" / "navqa" / SEQ / "qa_unfilled.json", qs)
    write_coda_frames(pkg / "coda_data" / SEQ)
    return pkg


def write_raven_release(repo: Path, slip: bool = True) -> Path:
    """The RAVEN repository's NaVQA: data_vlm/navqa/{data.csv, 0/qa_unfilled.json} (UTC-5) and
    coda_data/0 at the repository root."""
    qs = QUESTIONS + ([SLIP] if slip else [])
    write_data_csv(repo / "data_vlm" / "navqa" / "data.csv", RAVEN_H, qs)
    write_qa_unfilled(repo / "data_vlm" / "navqa" / SEQ / "qa_unfilled.json", qs)
    write_coda_frames(repo / "coda_data" / SEQ)
    return repo


# ------------------------------------------------------------------------------------ FindingDory
FD_COLOURS = ["red"] * 4 + ["green"] * 5 + ["blue"] * 3  # frame i at 06:00 + i / 4.168 min
FD_ROWS = [
    # (question, per-goal accepted frames, high-level category, low-level category)
    (
        "The robot's goal is: Revisit all the receptacles you placed objects on yesterday.",
        [[0, 1], [9, 10, 11]],
        "Multi-Goal Tasks",
        "Unordered Revisitation",
    ),
    (
        "The robot's goal is: Revisit all the objects you interacted with yesterday in specific order. "
        "The order to revisit them is: second, first.",
        [[9, 10], [0, 1]],
        "Multi-Goal Tasks",
        "Ordered Revisitation",
    ),
    (
        "The robot's goal is: Revisit all the receptacles you picked objects from yesterday.",
        [[0, 1], [9, 10, 11]],
        "Multi-Goal Tasks",
        "Unordered Revisitation",
    ),
    (
        "The robot's goal is: Navigate to the receptacle that you interacted with at 6:01 yesterday.",
        [[4]],
        "Single-Goal Temporal Tasks",
        "Time-Based",
    ),
]


def findingdory_forms_policy(body: dict[str, Any]) -> dict[str, Any]:
    """A model answering each multi-goal instruction in another release's form: the RAVEN
    prompt's space-separated "time" (06:00:00 = frame 0, 06:02:10 = frame 9), FindingDory's
    own "frame_indices", and our "Goal times:" line (its second goal wrong)."""
    q = question_of(body).lower()
    if "placed objects on" in q:
        return answer(question_type="time", answer="Both receptacles.", time="06:00:00 06:02:10")
    if "specific order" in q:
        return answer(question_type="time", answer="The second, then the first.", frame_indices=[9, 0])
    if "picked objects from" in q:
        return answer(question_type="time", answer="Goal times: 06:00:00 06:00:30", time="06:00:00")
    return answer(question_type="time", answer="At 06:01.", time="06:01:00")


def write_findingdory_release(root: Path) -> Path:
    """yali30/findingdory as downloaded: data/validation-00000-of-00001.parquet and
    videos/val/ep_1.mp4 beside it."""
    import pyarrow as pa
    import pyarrow.parquet as pq

    write_video(root / "videos" / "val" / "ep_1.mp4", FD_COLOURS)
    rows = [
        {
            "ep_id": "ep_1",
            "video": "videos/val/ep_1.mp4",
            "question": q,
            "answer": json.dumps(a),
            "task_id": f"task_{k}",
            "high_level_category": hi,
            "low_level_category": lo,
            "num_interactions": 2,
        }
        for k, (q, a, hi, lo) in enumerate(FD_ROWS)
    ]
    (root / "data").mkdir(parents=True, exist_ok=True)
    pq.write_table(pa.Table.from_pylist(rows), root / "data" / "validation-00000-of-00001.parquet")
    return root
