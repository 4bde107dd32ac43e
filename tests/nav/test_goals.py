"""goal_for: from an agent's Answer to an A* path and a goal pose on the memory's own map."""

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
from ravenmem.nav.goals import (  # noqa: E402
    goal_for,
    read_pose_stamped,  # noqa: E402
    to_map_xy,
)
from ravenmem.nav.mapping import MapBuilder, recording_config  # noqa: E402


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
    gp = goal_for(_answer(mem, target.id), mem)
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
    gp = goal_for(Answer(found=False, text="not found"), tum_like)
    assert not gp.ok and "no position" in gp.reason and gp.goal is None and gp.problem == "answer"
    far = Answer(found=True, position=[0.0, 0.0, 40.0])  # 40 m away along the map's x
    gp = goal_for(far, tum_like)
    assert not gp.ok and "unreachable" in gp.reason and gp.problem == "goal"
    gp = goal_for(_answer(tum_like, 1), tum_like, start=(55.0, 55.0))
    assert not gp.ok and "start" in gp.reason and gp.problem == "start"
    bare = ravenmem.create(tmp_path / "bare.mem", embedder=color_embedder, ocr=False)
    gp = goal_for(far, bare)
    assert not gp.ok and gp.problem == "map" and "no map.npz" in gp.reason
    d = gp.as_dict()
    assert d["pose_stamped"] is None and d["frame_id"] == "map" and d["map_id"] == "memory:bare.mem"


def test_unsupported_and_failed_answers_and_answers_of_another_map_are_refused(
    tum_like: ravenmem.Memory,
) -> None:
    good = _answer(tum_like, 5)
    assert goal_for(good, tum_like).ok
    unsupported = good.model_copy()
    object.__setattr__(unsupported, "unsupported", True)  # the models branch's flag, read if present
    object.__setattr__(unsupported, "support_distance", 7.25)
    gp = goal_for(unsupported, tum_like)
    assert not gp.ok and gp.problem == "answer" and "7.2 m from every memory" in gp.reason
    assert goal_for(unsupported, tum_like, allow_unsupported=True).ok
    failed = good.model_copy(update={"failed": True, "error": "model timed out"})
    gp = goal_for(failed, tum_like)
    assert not gp.ok and gp.problem == "answer" and "model timed out" in gp.reason
    other = good.model_copy(update={"map_id": "warehouse-2"})
    gp = goal_for(other, tum_like)
    assert not gp.ok and gp.problem == "map"
    assert "'warehouse-2'" in gp.reason and repr(tum_like.map_id) in gp.reason  # both maps named
    same = good.model_copy(update={"map_id": tum_like.map_id})
    assert goal_for(same, tum_like).ok


def test_heading_without_evidence_follows_the_path(tum_like: ravenmem.Memory) -> None:
    a = _answer(tum_like, 3)
    a.evidence = []
    a.yaw = 1.0  # a yaw about world z, on a map whose up is world y: not a map heading
    gp = goal_for(a, tum_like)
    assert gp.ok and gp.heading is not None and gp.heading.source == "path"
    (ax, ay), (bx, by) = gp.plan.waypoints[-2:]
    assert gp.goal[2] == pytest.approx(math.atan2(by - ay, bx - ax))
    assert np.isfinite(gp.plan.length_m)
    assert gp.as_dict()["heading"] == {"yaw": gp.goal[2], "source": "path", "reason": gp.heading.reason}


def test_a_models_yaw_on_a_map_whose_up_is_not_world_z_gives_way_to_the_evidence_view(
    tum_like: ravenmem.Memory,
) -> None:
    a = _answer(tum_like, 7)
    a.yaw, a.yaw_source = 2.5, "model"  # about world z: meaningless on this y-up recording
    gp = goal_for(a, tum_like)
    assert gp.ok and gp.goal[2] == pytest.approx(0.25 * math.sin(6), abs=1e-3)
    assert gp.heading is not None and gp.heading.source == "evidence"
    assert any("not this map's up" in n for n in gp.notes)


def test_on_a_z_up_map_the_models_yaw_is_the_heading_and_a_snapped_goal_faces_the_target(
    tmp_path: Path, color_embedder
) -> None:
    mem, grid = _room(tmp_path, color_embedder)
    a = Answer(found=True, position=[2.0, 2.0, 0.0], yaw=-2.0, yaw_source="model")
    gp = goal_for(a, mem, start=(1.0, 1.0))
    assert gp.ok and gp.heading.source == "model" and gp.goal[2] == -2.0
    # inside the box in the middle of the room: moved out, facing the box
    boxed = Answer(found=True, position=[5.0, 2.5, 0.0])
    gp = goal_for(boxed, mem, start=(1.0, 1.0))
    assert gp.ok and gp.plan.snapped and gp.heading.source == "target"
    gx, gy, yaw = gp.goal
    assert math.dist((gx, gy), (5.0, 2.5)) > 0.3
    assert yaw == pytest.approx(math.atan2(2.5 - gy, 5.0 - gx))
    assert gp.frame_id == "map" and gp.pose_stamped()["header"]["frame_id"] == "map"


def test_a_start_closed_off_from_the_goal_is_blamed_not_the_goal(tmp_path: Path, color_embedder) -> None:
    """As `navigate --to 20,-10` on E1M2 from the path's end behind one-way ledges: a small
    closed-off region around the start, the goal in the big one. The start is the problem."""
    mem, grid = _room(tmp_path, color_embedder)
    gp = goal_for(Answer(found=True, position=[2.0, 2.0, 0.0]), mem, start=(8.5, 4.5))  # the closet
    assert not gp.ok and gp.problem == "start", gp.reason
    assert "cut off from the goal" in gp.reason and "give another start" in gp.reason
    gp = goal_for(Answer(found=True, position=[9.0, 5.0, 0.0]), mem, start=(1.0, 1.0), snap_radius=0.5)
    assert not gp.ok and gp.problem == "goal", gp.reason


def _room(tmp_path: Path, color_embedder) -> tuple[ravenmem.Memory, object]:
    """A 10 x 6 m z-up room: a 1 x 1 m box at (5, 2.5), a closet walled off at x > 8, y > 4."""
    from ravenmem.nav.grid import MapConfig, OccupancyGrid

    mem = ravenmem.create(tmp_path / "room.mem", embedder=color_embedder, ocr=False)
    grid = OccupancyGrid(MapConfig(resolution=0.1, robot_radius=0.2))
    for x in np.arange(0.0, 10.01, 0.25):
        for y in np.arange(0.0, 6.01, 0.25):
            grid.mark_free_disc(float(x), float(y), 0.3, floor_z=0.0)

    def wall(cells: tuple[slice, slice]) -> None:
        grid.logodds[cells] = grid.config.l_clamp
        grid.known[cells] = True

    r0, c0 = grid.world_to_cell(4.5, 2.0)
    r1, c1 = grid.world_to_cell(5.5, 3.0)
    wall((slice(r0, r1 + 1), slice(c0, c1 + 1)))
    ra, ca = grid.world_to_cell(8.0, 4.0)
    rb, cb = grid.world_to_cell(10.0, 6.0)
    wall((slice(ra, ra + 2), slice(ca, cb + 1)))  # y = 4: the closet's wall
    wall((slice(ra, rb + 1), slice(ca, ca + 2)))  # x = 8
    grid.touch()
    grid.save(mem.path)
    return mem, grid
