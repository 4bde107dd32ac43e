from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from ravenmem.errors import InputError
from ravenmem.eval.datasets import load_dataset
from ravenmem.eval.datasets.frames import BASE_DAY
from ravenmem.eval.datasets.ravenqa import export_episode
from ravenmem.types import Frame, Pose
from tests.eval.eval_helpers import solid, write_raven_video


def test_layout_times_positions_and_answer_forms(raven_root: Path) -> None:
    (ep,) = load_dataset(f"raven-qa:{raven_root.parent}")  # a folder of splits
    assert ep.id == "real_world/vid_a" and ep.meta["subset"] == "real_world" and ep.meta["split"] == ""
    # 00:10:00 at frame 1, 00:10:18 at frame 10: 2 s per frame in between
    assert ep.frame_times[0] == BASE_DAY + 600.0
    assert np.allclose(np.diff(ep.frame_times), 2.0)
    assert ep.frame_files[4] == "frame_005.jpg"
    q = {x.text: x for x in ep.questions}
    blue = q["Where did you see the blue wall?"]
    assert blue.type == "frame" and blue.truth.files == ["frame_005.jpg"]  # the paper's target: the frame
    assert blue.truth.positions == [[4.0, 0.0, 0.0]]  # from filename_to_position
    assert blue.category == "dominant"
    yellow = q["Where was something yellow?"]
    assert yellow.type == "position" and yellow.truth.positions == [[6.0, 0.0, 0.0], [7.0, 0.0, 0.0]]
    assert ep.frame_tol == pytest.approx(1.0)  # half a frame period: the nearest frame must be the named one
    red = q["Where was the red thing?"]
    assert red.truth.files == ["frame_001.jpg", "frame_002.jpg"] and len(red.truth.positions) == 2
    frames = list(ep.frames())
    assert len(frames) == 10 and frames[4].pose is not None and frames[4].pose.x == 4.0
    assert frames[4].image.shape == (24, 32, 3) and frames[4].image[0, 0, 2] > 200  # blue


def test_frame_order_rate_without_maps_and_file_only_scoring(tmp_path: Path) -> None:
    v = write_raven_video(
        tmp_path / "split" / "v1", questions=[["Where is the white door?", "frame_009.jpg"]]
    )
    doc = json.loads((v / "questions.json").read_text())
    doc = {
        "questions (ques, answer_in_position)": doc[
            "questions (ques, answer_in_filename, category, query_img)"
        ]
    }
    (v / "questions.json").write_text(json.dumps(doc))
    (ep,) = load_dataset(f"raven-qa:{tmp_path / 'split'}", rate=0.5)
    assert np.allclose(np.diff(ep.frame_times), 2.0) and ep.frame_times[0] == BASE_DAY
    assert not ep.has_poses
    (q,) = ep.questions
    assert q.type == "frame" and q.truth.files == ["frame_009.jpg"] and not q.truth.positions


def test_bad_answers_and_layouts_name_the_file(tmp_path: Path) -> None:
    v = write_raven_video(tmp_path / "s" / "v", questions=[["Where?", {"x": 1}, "spatial", None]])
    with pytest.raises(InputError, match=r"questions.json question 0: answer"):
        load_dataset(f"raven-qa:{v}")
    v2 = write_raven_video(
        tmp_path / "s2" / "v", questions=[["Where?", "frame_001.jpg", "spatial", "nope.jpg"]]
    )
    with pytest.raises(InputError, match="query image 'nope.jpg' not found"):
        load_dataset(f"raven-qa:{v2}")
    (tmp_path / "empty").mkdir()
    with pytest.raises(InputError, match="no <video>/questions.json"):
        load_dataset(f"raven-qa:{tmp_path / 'empty'}")
    v3 = write_raven_video(
        tmp_path / "s3" / "v",
        timestamp_to_filename={"00:00:09": "frame_001.jpg", "00:00:02": "frame_005.jpg"},
    )
    with pytest.raises(InputError, match="do not increase"):
        load_dataset(f"raven-qa:{v3}")


def test_query_image_is_found(tmp_path: Path) -> None:
    v = write_raven_video(
        tmp_path / "s" / "v",
        questions=[["Where did you see this?", "frame_003.jpg", "dominant", "query_images/q1.jpg"]],
    )
    from tests.eval.eval_helpers import save

    save(v / "query_images" / "q1.jpg", solid("green"))
    (ep,) = load_dataset(f"raven-qa:{v}")
    assert ep.questions[0].image == v / "query_images" / "q1.jpg"


def test_export_round_trip(tmp_path: Path) -> None:
    frames = [
        Frame(image=solid(c), t=BASE_DAY + 3600 + 0.5 * i, pose=Pose(float(i), 2.0 * i, 0.0))
        for i, c in enumerate(["red", "green", "blue", "white"])
    ]
    out = export_episode(
        tmp_path / "sim" / "ep0",
        frames,
        [
            {
                "question": "Where is the blue cube?",
                "answer": [[2.0, 4.0, 0.0], "frame_000002.jpg"],
                "category": "spatial",
            }
        ],
    )
    (ep,) = load_dataset(f"raven-qa:{out}")
    assert ep.has_poses and len(ep.frame_files) == 4
    assert ep.frame_times[0] == BASE_DAY + 3600 and ep.frame_times[2] == pytest.approx(BASE_DAY + 3601)
    (q,) = ep.questions
    assert q.truth.positions == [[2.0, 4.0, 0.0]] and q.truth.files == ["frame_000002.jpg"]
    poses = [f.pose.xyz for f in ep.frames()]  # type: ignore[union-attr]
    assert poses[3] == (3.0, 6.0, 0.0)


def test_subsets_and_simple_hard_splits(tmp_path: Path, scoring_root: Path) -> None:
    eps = load_dataset(f"raven-qa:{scoring_root}")
    assert [e.id for e in eps] == ["real_world/hard/vid_c", "sim/hard/ep_b", "sim/simple/ep_a"]
    assert {(q.subset, q.split) for e in eps for q in e.questions} == {
        ("real_world", "hard"),
        ("sim", "hard"),
        ("sim", "simple"),
    }
    # a split folder or a video given directly keeps its subset and split
    (ep,) = load_dataset(f"raven-qa:{scoring_root / 'sim' / 'simple'}")
    assert ep.id == "sim/simple/ep_a" and all(q.type == "frame" and q.truth.positions for q in ep.questions)
    (ep,) = load_dataset(f"raven-qa:{scoring_root / 'sim' / 'hard' / 'ep_b'}")
    assert ep.meta["subset"] == "sim" and ep.meta["split"] == "hard"
    assert {e.pos_threshold for e in eps} == {2.0}  # our default; per-subset thresholds are the scorer's
    # without split folders: a top-level "split", or a fifth element per question
    v = write_raven_video(tmp_path / "web" / "v1", split="HARD")
    doc = json.loads((v / "questions.json").read_text())
    key = "questions (ques, answer_in_filename, category, query_img)"
    doc[key][0] = [*doc[key][0], "simple"]
    (v / "questions.json").write_text(json.dumps(doc))
    (ep,) = load_dataset(f"raven-qa:{tmp_path / 'web'}")
    assert ep.id == "web/hard/v1" and [q.split for q in ep.questions] == ["simple", "hard", "hard", "hard"]
    assert "timestamp_to_filename" in ep.meta["time_rule"]
