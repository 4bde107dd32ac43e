"""Small benchmark folders in the layouts the public releases use, generated from their documented
field names (nothing is copied from the releases): the RAVEN repository's and ReMEmbR's NaVQA,
the RAVEN-QA release's subsets, FindingDory's rows with multi-goal answers; and a scripted VLM
policy that answers them over real HTTP."""

from __future__ import annotations

import csv
import json
import pickle
import re
from datetime import datetime, timedelta, timezone
from pathlib import Path
from typing import Any

import numpy as np

from tests.agent.scripted_server import answer, tool
from tests.eval.eval_helpers import COLORS, NAVQA_HEADER, save, solid, write_video

NAV_T0 = 1673884500.0  # 2023-01-16 15:55:00 UTC: 10:55:00 in the RAVEN release's UTC-5, 07:55:00 in ReMEmbR's UTC-8
NAV_COLORS = ["red"] * 10 + ["green"] * 10 + ["blue"] * 10  # frame i at NAV_T0 + i s, x = i m


def clock(t: float, offset_h: int, day: bool = False) -> str:
    d = datetime.fromtimestamp(t, timezone(timedelta(hours=offset_h)))
    return d.strftime("%Y-%m-%d %H:%M:%S") if day else f"{d.hour}:{d.minute:02d}:{d.second:02d}"


def write_coda(folder: Path, n: int = 30) -> None:
    """CODa frame pickles as the releases' preprocessing writes them: cam0 (BGR), position,
    rotation (quaternion), timestamp; one file per frame named by its Unix time."""
    folder.mkdir(parents=True, exist_ok=True)
    for i in range(n):
        d = {
            "cam0": solid(NAV_COLORS[i % len(NAV_COLORS)], 16, 16)[..., ::-1].copy(),
            "position": np.array([float(i), 0.0, 0.0]),
            "rotation": np.array([0.0, 0.0, 0.0, 1.0]),
            "timestamp": NAV_T0 + i,
        }
        (folder / f"{NAV_T0 + i:.6f}.pkl").write_bytes(pickle.dumps(d, protocol=pickle.HIGHEST_PROTOCOL))


# (id, type, question, window (s from NAV_T0), truth instants (s), parsable answer, text answer)
NAV_QUESTIONS = [
    ("SHORT_pos", "position", "Where is the blue wall?", (5, 29), [28], "[position]", ""),
    ("SHORT_no", "binary", "Did you see a purple car?", (0, 20), [12], "no", ""),
    ("MEDIUM_time", "time", "When did you see the green wall?", (0, 29), [15], "[minutes] ago", ""),
    ("LONG_dur", "duration", "How long did you see green walls?", (1, 29), [10, 20], "0.1667", ""),
    ("LONG_late", "time", "When did you see the red wall?", (10, 29), [2], "[minutes] ago", ""),
]


def _data_csv(path: Path, rows: list[list[str]]) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="", encoding="utf-8") as f:
        w = csv.writer(f)
        w.writerow(NAVQA_HEADER)
        w.writerows(rows)


def _csv_rows(seq: str, offset_h: int) -> list[list[str]]:
    return [
        [
            qid,
            seq,
            text,
            ",".join(clock(NAV_T0 + s, offset_h) for s in stamps),
            qtype,
            "",
            parsable,
            "spatial",
        ]
        for qid, qtype, text, _, stamps, parsable, _ in NAV_QUESTIONS
    ]


def _clip(qid: str, window: tuple[int, int]) -> dict[str, Any]:
    t0, t1 = NAV_T0 + window[0], NAV_T0 + window[1]
    cat = qid.split("_")[0]
    return {
        "id": qid,
        "length_category": cat,
        "length": t1 - t0,
        "start_time": t0,
        "end_time": t1,
        "file_info": {"qa_start_filename": f"{t0:.6f}.pkl", "qa_end_filename": f"{t1:.6f}.pkl"},
    }


def _write_json(path: Path, doc: Any) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(doc, indent=1), encoding="utf-8")


def write_raven_navqa(repo: Path, missing_seq: str = "3") -> Path:
    """The RAVEN repository's NaVQA files for sequence 0 (data.csv in UTC-5, qa_unfilled.json,
    human_qa.json with its "You started moving at" texts) and coda_data/0 at the root; data.csv
    also names `missing_seq`, whose frames are not there."""
    data = repo / "data_vlm"
    rows = _csv_rows("0", -5) + [
        [
            f"{missing_seq}_SHORT_{k}",
            missing_seq,
            "Where?",
            "11:00:00",
            "position",
            "",
            "[position]",
            "spatial",
        ]
        for k in range(2)
    ]
    _data_csv(data / "navqa" / "data.csv", rows)
    _write_json(
        data / "navqa" / "0" / "qa_unfilled.json",
        {"version": 0.1, "data": [_clip(q[0], q[3]) for q in NAV_QUESTIONS]},
    )
    items = []
    for qid, qtype, text, window, stamps, parsable, _ in NAV_QUESTIONS:
        item = _clip(qid, window)
        t0, t1 = item["start_time"], item["end_time"]
        head = f"You started moving at {clock(t0, -5, True)}. The current time is {clock(t1, -5, True)} and you are located at [{window[1]:.2f}, 0.0, 0.0]. \n "
        ans: dict[str, Any]
        if qtype == "position":
            ans = {"position": [float(stamps[0]), 0.0, 0.0]}
        elif qtype == "time":
            ans = {"text": ["x minutes ago"], "time": round((t1 - (NAV_T0 + stamps[0])) / 60.0, 4)}
        elif qtype == "duration":
            ans = {"text": [f"{parsable} minutes"], "duration": float(parsable)}
        else:
            ans = {"text": [parsable, parsable]}
        items.append(item | {"question": head + text, "type": qtype, "context": "", "answers": ans})
    _write_json(data / "questions" / "0" / "human_qa.json", {"version": 0.1, "data": items})
    write_coda(repo / "coda_data" / "0")
    (repo / "raven").mkdir(exist_ok=True)  # the package folder beside data_vlm/
    return repo


def write_remembr_navqa(repo: Path) -> Path:
    """ReMEmbR's NaVQA files as shipped: remembr/data/navqa/data.csv (UTC-8 clock times) and the
    clips in remembr/data/navqa/0/qa_unfilled.json; frames in remembr/coda_data/0."""
    pkg = repo / "remembr"
    _data_csv(pkg / "data" / "navqa" / "data.csv", _csv_rows("0", -8))
    _write_json(
        pkg / "data" / "navqa" / "0" / "qa_unfilled.json",
        {"version": 0.1, "data": [_clip(q[0], q[3]) for q in NAV_QUESTIONS]},
    )
    write_coda(pkg / "coda_data" / "0")
    return repo


def question_of(body: dict[str, Any]) -> str:
    """The question the agent was asked (the first user message's text)."""
    user = next(m for m in body["messages"] if m["role"] == "user")
    c = user["content"]
    texts = [c] if isinstance(c, str) else [p.get("text", "") for p in c if p.get("type") == "text"]
    return " ".join(texts)


def navqa_policy(body: dict[str, Any]) -> dict[str, Any]:
    """A scripted VLM: "No" to the purple car, 10 s for how long; otherwise search the colour
    the question names and answer with the first memory listed."""
    q = question_of(body).lower()
    if "purple car" in q:
        return answer(question_type="binary", answer="No, I did not see one.", yes=False, found=False)
    if "how long" in q:
        return answer(question_type="duration", answer="About 10 s.", duration_s=10)
    tool_msgs = [m for m in body["messages"] if m["role"] == "tool"]
    if not tool_msgs:
        colour = next(w for w in re.findall(r"[a-z]+", q.split("question:")[-1]) if w in COLORS)
        return tool("search_text", query=colour)
    first = re.search(r"^\[m(\d+)\]", tool_msgs[-1]["content"], re.M)
    kind = "position" if "where" in q else "time"
    return answer(question_type=kind, answer="there", evidence=[int(first.group(1))] if first else [])


# RAVEN-QA release: data/{habitat_sim,real_world,irs,irs_hard}/[<group>/]<video>/frames + questions.json
QA_N = 12  # frames per video, 1 s and 3 m apart; frame k shows a colour when it is a target
QA_TARGETS = {"red": 3, "blue": 8}


def write_release_video(vdir: Path, stamps: str = "filename", offset_m: float = 1.5) -> Path:
    """One RAVEN-QA video: the answer positions sit `offset_m` from the answer frame's camera (so
    position accuracy depends on the threshold); `stamps`: "filename" stamps every frame in
    timestamp_to_filename, "position" in timestamp_to_position by file name, "ends" only the
    first and last frames."""
    for i in range(QA_N):
        colour = next((c for c, j in QA_TARGETS.items() if j == i), "grey")
        save(vdir / "frames" / f"frame_{i + 1:03d}.jpg", solid(colour))
    rows = [
        [
            f"Where did you see the {c} sign?",
            [[3.0 * j + offset_m, 0.0, 0.0], f"frame_{j + 1:03d}.jpg"],
            "dominant",
            None,
        ]
        for c, j in QA_TARGETS.items()
    ]
    every = {f"00:10:{i:02d}": f"frame_{i + 1:03d}.jpg" for i in range(QA_N)}
    ends = {"00:10:00": "frame_001.jpg", f"00:10:{QA_N - 1:02d}": f"frame_{QA_N:03d}.jpg"}
    doc: dict[str, Any] = {
        "questions (ques, answer_in_filename, category, query_img)": rows,
        "filename_to_position": {f"frame_{i + 1:03d}.jpg": [3.0 * i, 0.0, 0.0] for i in range(QA_N)},
    }
    if stamps == "position":
        doc["timestamp_to_position"] = every
    else:
        doc["timestamp_to_filename"] = every if stamps == "filename" else ends
    _write_json(vdir / "questions.json", doc)
    return vdir


def write_raven_qa_release(data: Path) -> Path:
    """The four release subsets: irs (simple, with an indoor/ group folder and file names in
    timestamp_to_position), irs_hard (hard), habitat_sim and real_world (one of them stamped at
    its ends only)."""
    write_release_video(data / "irs" / "indoor" / "vid_a", stamps="position")
    write_release_video(data / "irs_hard" / "vid_b")
    write_release_video(data / "habitat_sim" / "ep_1")
    write_release_video(data / "real_world" / "walk_1", stamps="ends")
    return data


def write_findingdory_goals(root: Path) -> Path:
    """A FindingDory folder whose rows need the release's normalisations and a multi-goal answer."""
    write_video(root / "videos" / "validation" / "ep_id_3.mp4", ["red"] * 4 + ["green"] * 5 + ["blue"] * 3)
    rows = [
        (
            "The robot's goal is: Navigate to the red box, then to the blue box.",
            "[[0, 1], [9, 10, 11]]",
            "Multi-Goal Tasks",
        ),
        ("The robot's goal is: Navigate to what you saw at 6:01.", "[[4]]", "Single-Goal Temporal Tasks"),
        ("The robot's goal is: Navigate to the purple sofa.", "[[-1]]", "Single-Goal Spatial Tasks"),
    ]
    lines = [
        json.dumps(
            {
                "ep_id": "3",
                "video": "videos/validation/ep_id_3.mp4",
                "question": q,
                "answer": a,
                "task_id": f"t{k}",
                "high_level_category": cat,
                "low_level_category": "x",
                "num_interactions": 2,
            }
        )
        for k, (q, a, cat) in enumerate(rows)
    ]
    (root / "validation.jsonl").write_text("\n".join(lines) + "\n", encoding="utf-8")
    return root


def findingdory_policy(body: dict[str, Any]) -> dict[str, Any]:
    """Answers every goal's time as the question's instructions ask (the frames' in-game clock:
    frame i at 06:00 + i / 4.168 min)."""
    q = question_of(body).lower()
    if "purple sofa" in q:
        return answer(question_type="time", answer="Not found.", found=False)
    if "red box, then to the blue box" in q:
        return answer(question_type="time", answer="Goal times: 06:00:00 06:02:10", time="06:00:00")
    return answer(question_type="time", answer="Goal times: 06:01:00", time="06:01:00")
