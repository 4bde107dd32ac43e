from __future__ import annotations

import json
import pickle
from pathlib import Path

import numpy as np
import pytest

from ravenmem.errors import InputError
from ravenmem.eval.datasets import load_dataset
from ravenmem.eval.datasets.findingdory import FRAMES_PER_MINUTE, frame_of_time, frame_time
from ravenmem.eval.datasets.frames import BASE_DAY
from ravenmem.eval.datasets.navqa import POS_THRESHOLD, read_coda_pickle
from tests.eval.eval_helpers import T0, solid, write_findingdory, write_navqa


def test_navqa_human_qa_clips(tmp_path: Path) -> None:
    eps = load_dataset(f"navqa:{write_navqa(tmp_path / 'navqa')}")
    assert [len(e.questions) for e in eps] == [3, 2]  # clip [T0, T0+19] and clip [T0+5, T0+15]
    long_ep, short_ep = eps
    assert len(short_ep.frame_times) == 11 and short_ep.frame_times[0] == T0 + 5
    assert short_ep.pos_threshold == POS_THRESHOLD == 15.0
    q = {x.id: x for e in eps for x in e.questions}
    assert q["SHORT_a"].truth.positions == [[0.0, 22.0, 0.0]]
    assert q["SHORT_a"].category == "spatial" and q["SHORT_a"].horizon == "short"
    # the question carries where the robot is now (last frame of its clip: y = 2 * 15)
    assert q["SHORT_a"].text.startswith("You are now at position [0.00, 30.00, 0.00]")
    assert q["SHORT_a"].text.endswith("Where is the blue door?")
    assert q["SHORT_b"].truth.times == [pytest.approx(T0 + 15 - 9.0)]  # 0.15 min before the clip's end
    assert q["LONG_c"].truth.yes is True and q["LONG_c"].horizon == "long"
    assert q["LONG_d"].truth.duration == pytest.approx(4.002)
    assert q["LONG_e"].truth.text == ["It was red"] and q["LONG_e"].category == "descriptive"
    frames = list(short_ep.frames())
    assert len(frames) == 11 and frames[0].pose.y == 10.0  # type: ignore[union-attr]


def test_navqa_csv_only_uses_local_time_and_poses(tmp_path: Path) -> None:
    root = write_navqa(tmp_path / "navqa", with_human_qa=False)
    # our flat layout names no release and no text says the zone: the data does (Chicago in January)
    (inferred,) = load_dataset(f"navqa:{root}")
    assert "UTC-6 (inferred from the data: UTC-6 puts" in inferred.meta["zone"]
    (ep,) = load_dataset(f"navqa:{root}", tz="America/Chicago")
    assert [q.truth for q in inferred.questions] == [q.truth for q in ep.questions]
    q = {x.id: x for x in ep.questions}
    assert len(ep.frame_times) == 20
    # 9:55:11 America/Chicago = T0 + 11 s: the pose there is y = 22
    assert q["SHORT_a"].truth.positions == [[0.0, 22.0, 0.0]]
    assert q["SHORT_b"].truth.times == [T0 + 6]
    assert q["LONG_d"].truth.duration == pytest.approx(4.002)
    (ep_utc,) = load_dataset(f"navqa:{tmp_path / 'navqa'}", tz="UTC")
    assert {x.id: x for x in ep_utc.questions}["SHORT_b"].truth.times != [T0 + 6]


def test_navqa_coda_pickles_and_refuses_code(tmp_path: Path) -> None:
    root = write_navqa(tmp_path / "navqa")
    import shutil

    shutil.rmtree(root / "frames")
    pdir = root / "coda_data" / "0"
    pdir.mkdir(parents=True)
    for i in range(20):
        bgr = solid("blue")[..., ::-1].copy()
        d = {
            "cam0": bgr,
            "position": np.array([1.0, 2.0 * i, 0.5]),
            "rotation": np.array([0, 0, 0, 1.0]),
            "timestamp": T0 + i,
            "bbox_3d": {},
        }
        (pdir / f"{T0 + i}.pkl").write_bytes(pickle.dumps(d, protocol=pickle.HIGHEST_PROTOCOL))
    eps = load_dataset(f"navqa:{root}")
    frame = next(iter(eps[1].frames()))
    assert frame.image[0, 0, 2] > 200 and frame.image[0, 0, 0] < 50  # BGR came back as RGB blue
    assert frame.pose is not None and frame.pose.xyz == (1.0, 10.0, 0.5) and frame.t == T0 + 5

    class Evil:
        def __reduce__(self):  # type: ignore[no-untyped-def]
            import os

            return (os.system, ("echo pwned > /dev/null",))

    bad = tmp_path / "evil.pkl"
    bad.write_bytes(pickle.dumps({"cam0": Evil(), "position": [0, 0, 0]}))
    with pytest.raises(InputError, match="refusing to load posix.system|refusing to load os.system"):
        read_coda_pickle(bad)


def test_navqa_errors(tmp_path: Path) -> None:
    root = write_navqa(tmp_path / "navqa")
    hq = root / "questions" / "0" / "human_qa.json"
    data = json.loads(hq.read_text())
    data["data"][0]["type"] = "colour"
    hq.write_text(json.dumps(data))
    with pytest.raises(InputError, match=r"human_qa.json item 0: type 'colour'"):
        load_dataset(f"navqa:{root}")
    (tmp_path / "x").mkdir()
    with pytest.raises(InputError, match="no data.csv"):
        load_dataset(f"navqa:{tmp_path / 'x'}")


@pytest.mark.parametrize("fmt", ["jsonl", "parquet"])
def test_findingdory_rows_video_and_clock(tmp_path: Path, fmt: str) -> None:
    (ep,) = load_dataset(f"findingdory:{write_findingdory(tmp_path / 'fd', fmt)}")
    assert len(ep.frame_times) == 12 and not ep.has_poses
    assert ep.frame_times[0] == BASE_DAY + 6 * 3600  # 06:00 in-game
    assert ep.frame_times[1] - ep.frame_times[0] == pytest.approx(60.0 / FRAMES_PER_MINUTE)
    assert frame_of_time(frame_time(11)) == 11
    q = {x.meta["task_id"]: x for x in ep.questions}
    assert q["t1"].truth.frames == [[4, 5, 6, 7]] and q["t1"].category == "single-goal spatial tasks"
    assert q["t2"].truth.frames == [[0, 1], [9, 10, 11]] and q["t2"].meta["goals"] == 2
    assert q["t3"].truth.none and q["t3"].truth.frames == []
    frames = list(ep.frames())
    assert len(frames) == 12 and frames[5].t == ep.frame_times[5]
    assert frames[5].image[..., 1].mean() > 150  # green


def test_findingdory_errors(tmp_path: Path) -> None:
    root = write_findingdory(tmp_path / "fd")
    lines = (root / "validation.jsonl").read_text().splitlines()
    row = json.loads(lines[0])
    row["answer"] = "[[4, 'x']]"
    (root / "validation.jsonl").write_text(json.dumps(row) + "\n")
    with pytest.raises(InputError, match=r"validation.jsonl row 0: answer"):
        load_dataset(f"findingdory:{root}")
    row["answer"], row["video"] = "[[1]]", "videos/missing.mp4"
    (root / "validation.jsonl").write_text(json.dumps(row) + "\n")
    with pytest.raises(InputError, match="not found"):
        load_dataset(f"findingdory:{root}")
