"""plan_to_answer: from an agent's Answer to an A* path and a goal pose on the memory's own map."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from depthscene import INTR  # noqa: E402
from test_mapping import WORLD_Y_UP, _frames  # noqa: E402

import ravenmem  # noqa: E402
from ravenmem.agent.schema import Answer, Evidence  # noqa: E402
from ravenmem.errors import InputError  # noqa: E402
from ravenmem.nav.goals import plan_to_answer, to_map_xy  # noqa: E402
from ravenmem.nav.mapping import MapBuilder, recording_config  # noqa: E402
from ravenmem.nav.nav2 import read_pose_stamped  # noqa: E402


@pytest.fixture()
def tum_like(tmp_path: Path, color_embedder) -> ravenmem.Memory:
    """A memory recorded in a y-up world (like TUM's motion-capture frame) with its depth map."""
    frames = _frames(WORLD_Y_UP, n=12)
    mem = ravenmem.create(tmp_path / "m.mem", embedder=color_embedder, ocr=False, thumb_size=0)
    mem.add_frames(frames)
    b = MapBuilder(mem.path, INTR, "optical", recording_config(resolution=0.05), fit_frames=6)
    for f in frames:
        b.add(f)
    b.close()
    return mem


def _answer(mem: ravenmem.Memory, mid: int) -> Answer:
    (rec,) = mem.get([mid])
    p = rec.pose
    return Answer(
        question="where is it?",
        found=True,
        position=[p.x, p.y, p.z],
        yaw=p.yaw,
        position_source="evidence",
        evidence=[Evidence(id=rec.id, t=rec.t, x=p.x, y=p.y, z=p.z, yaw=p.yaw)],
    )


def test_goal_is_the_evidence_pose_facing_where_the_camera_looked(tum_like: ravenmem.Memory) -> None:
    mem = tum_like
    recs = mem.all_records()
    target = recs[6]
    gp = plan_to_answer(mem, _answer(mem, target.id))
    assert gp.ok, gp.plan.reason
    from ravenmem.nav import load_map

    grid = load_map(mem.path)
    want = to_map_xy(grid, target.pose.xyz)
    assert gp.target == pytest.approx(want)
    assert math.dist(gp.goal[:2], want) < 0.1  # the cell centre of the answer's place
    # the start is the robot's last pose: the end of the map's trajectory (the last frame)
    assert gp.start == pytest.approx(tuple(grid.trajectory[-1]), abs=1e-6)
    # the scene's x and y are the map's x and y here (up = world +y, snapped), so the heading
    # is the scene yaw the camera had (0.25 sin(i)), not the quaternion's yaw about world z
    scene_yaw = 0.25 * math.sin(6)
    assert gp.goal[2] == pytest.approx(scene_yaw, abs=1e-3)
    assert abs(target.pose.yaw - scene_yaw) > 0.3
    x, y, yaw, frame = read_pose_stamped(gp.pose_stamped())
    assert frame == "map" and (x, y) == pytest.approx(gp.goal[:2]) and yaw == pytest.approx(gp.goal[2])
    d = gp.as_dict()
    assert d["ok"] and d["path_length_m"] == pytest.approx(gp.plan.length_m) and d["waypoints"]


def test_answers_that_cannot_be_driven_to_say_why(
    tum_like: ravenmem.Memory, tmp_path: Path, color_embedder
) -> None:
    gp = plan_to_answer(tum_like, Answer(found=False, text="not found"))
    assert not gp.ok and "no position" in gp.plan.reason and gp.goal is None
    far = Answer(found=True, position=[0.0, 0.0, 40.0])  # 40 m away along the map's x
    gp = plan_to_answer(tum_like, far)
    assert not gp.ok and "unreachable" in gp.plan.reason
    gp = plan_to_answer(tum_like, _answer(tum_like, 1), start=(55.0, 55.0))
    assert not gp.ok and "start" in gp.plan.reason
    bare = ravenmem.create(tmp_path / "bare.mem", embedder=color_embedder, ocr=False)
    with pytest.raises(InputError, match="no map.npz"):
        plan_to_answer(bare, far)


def test_heading_falls_back_to_the_answer_yaw(tum_like: ravenmem.Memory) -> None:
    a = _answer(tum_like, 3)
    a.evidence = []
    a.yaw = 1.0
    gp = plan_to_answer(tum_like, a)
    assert gp.ok and gp.goal[2] == 1.0
    assert np.isfinite(gp.plan.length_m)


def test_a_models_yaw_on_a_map_whose_up_is_not_world_z_gives_way_to_the_evidence_view(
    tum_like: ravenmem.Memory,
) -> None:
    a = _answer(tum_like, 7)
    a.yaw, a.yaw_source = 2.5, "model"  # about world z: meaningless on this y-up recording
    gp = plan_to_answer(tum_like, a)
    assert gp.ok and gp.goal[2] == pytest.approx(0.25 * math.sin(6), abs=1e-3)
    assert any("not this map's up" in n for n in gp.notes)
