import json
import math

import numpy as np
import pytest

from ravenmem.errors import InputError
from ravenmem.nav import MapConfig, OccupancyGrid
from ravenmem.types import Intrinsics, Pose

INTR = Intrinsics.from_fov(160, 120, 90.0)
CAM_H = 1.0


def wall_depth(
    dist: float, wall_top: float = 2.5, intr: Intrinsics = INTR, cam_h: float = CAM_H
) -> np.ndarray:
    """Depth image of a level floor and a wall plane `dist` metres ahead, perpendicular to the
    optical axis, from `wall_top` down to the floor; nothing above the wall (0 = no reading)."""
    v = np.arange(intr.height, dtype=np.float64)[:, None] + 0.5
    down = (v - intr.cy) / intr.fy  # height drop per metre of depth
    with np.errstate(divide="ignore"):
        s_floor = np.where(down > 0, cam_h / down, np.inf)
    h_at_wall = cam_h - dist * down
    d = np.where(s_floor < dist, s_floor, np.where(h_at_wall <= wall_top, dist, 0.0))
    return np.repeat(d, intr.width, axis=1).astype(np.float32)


def test_intrinsics_from_fov() -> None:
    assert INTR.fx == pytest.approx(80.0) and INTR.cx == 80.0 and INTR.cy == 60.0
    assert INTR.hfov == pytest.approx(math.pi / 2)
    with pytest.raises(InputError):
        Intrinsics.from_fov(0, 10, 90)


@pytest.mark.parametrize("yaw", [0.0, math.pi / 2, -2.0])
def test_wall_ahead_is_occupied_space_before_free_behind_unknown(yaw: float) -> None:
    grid = OccupancyGrid(
        MapConfig(resolution=0.2, step_height=0.2, obstacle_max=1.5, explore_range=2.5, stride=2)
    )
    pose = Pose(1.0, -2.0, CAM_H, yaw)
    grid.integrate(wall_depth(4.1), pose, INTR, CAM_H)
    fwd = np.array([math.cos(yaw), math.sin(yaw)])

    left = np.array([-fwd[1], fwd[0]])

    def state(ahead: float, side: float = 0.0) -> str:
        c = grid.world_to_cell(*(np.array([pose.x, pose.y]) + ahead * fwd + side * left))
        if not grid.known[c]:
            return "unknown"
        return "occupied" if grid.occupied[c] else "free"

    def occupied_near(ahead: float, side: float) -> bool:
        r, c = grid.world_to_cell(*(np.array([pose.x, pose.y]) + ahead * fwd + side * left))
        return bool(grid.occupied[r - 1 : r + 2, c - 1 : c + 2].any())

    for side in (-1.5, 0.0, 1.5):
        assert occupied_near(4.1, side)
        for a in (2.0, 3.0, 3.7):  # inside the 90 degree field of view: |side| < ahead
            assert state(a, side) == "free", (a, side)
        assert state(4.7, side) == "unknown"  # behind the wall
    assert state(1.0) == "free"
    assert state(-1.0) == "unknown"  # behind the camera
    assert state(3.0, 3.5) == "unknown"  # outside the 90 degree field of view
    # explored = looked at within explore_range; farther free space is known but not explored
    assert grid.explored[grid.world_to_cell(*(np.array([pose.x, pose.y]) + 2.0 * fwd))]
    assert not grid.explored[grid.world_to_cell(*(np.array([pose.x, pose.y]) + 3.5 * fwd))]
    # occupied cells lie on the wall line (within a cell), all in front of the camera
    rr, cc = np.nonzero(grid.occupied)
    centres = np.stack([grid.origin[0] + (cc + 0.5) * 0.2, grid.origin[1] + (rr + 0.5) * 0.2], 1)
    along = (centres - [pose.x, pose.y]) @ fwd
    assert rr.size > 20 and np.all(np.abs(along - 4.1) < 0.2)


def test_low_step_is_free_and_tall_box_is_obstacle() -> None:
    # A step of 0.15 m (below step_height) and a box of 0.6 m: both as a vertical face 3 m ahead.
    cfg = MapConfig(resolution=0.1, step_height=0.2, obstacle_max=1.5)
    for top, expect in ((0.15, False), (0.6, True)):
        grid = OccupancyGrid(cfg)
        d = wall_depth(3.0, wall_top=top)
        d[d == 0.0] = 0.0  # rows above the face see nothing (open space beyond)
        grid.integrate(d, Pose(0, 0, CAM_H, 0.0), INTR, CAM_H)
        assert bool(grid.occupied[grid.world_to_cell(3.03, 0.0)]) is expect


def test_depth_size_must_match_camera() -> None:
    with pytest.raises(InputError):
        OccupancyGrid().integrate(np.zeros((10, 10), np.float32), Pose(0, 0), INTR, CAM_H)


def test_inflation_is_a_euclidean_disc() -> None:
    grid = OccupancyGrid(MapConfig(resolution=0.25, require_floor=False))
    grid.ensure(-3, -3, 3, 3)
    grid.known[:] = True
    grid.logodds[:] = -1.0
    c = grid.world_to_cell(0.1, 0.1)
    grid.logodds[c] = 2.0
    inf = grid.inflated(0.5)
    assert inf[c]
    assert inf[c[0] + 2, c[1]] and inf[c[0], c[1] - 2]  # 0.5 m straight
    assert not inf[c[0] + 3, c[1]]  # 0.75 m
    assert inf[c[0] + 1, c[1] + 1]  # 0.35 m diagonal
    assert not inf[c[0] + 2, c[1] + 2]  # 0.71 m diagonal: a square kernel would wrongly include it
    trav = grid.traversable(0.5)
    assert not trav[c[0] + 1, c[1]] and trav[c[0] + 3, c[1]]


def test_growth_keeps_world_positions_and_roundtrip(tmp_path) -> None:
    grid = OccupancyGrid(MapConfig(resolution=0.2))
    grid.mark_free_disc(1.0, 1.0, 0.3)
    grid.mark_blocked(1.0, 1.0, 0.0, 0.6)
    occ_before = grid.occupied[grid.world_to_cell(1.6, 1.0)]
    grid.ensure(-20.0, -15.0, 30.0, 2.0)
    assert grid.occupied[grid.world_to_cell(1.6, 1.0)] == occ_before == True  # noqa: E712
    assert grid.free[grid.world_to_cell(1.0, 1.0)]
    grid.save(tmp_path)
    back = OccupancyGrid.load(tmp_path)
    assert back.origin == pytest.approx(grid.origin) and back.resolution == 0.2
    assert np.array_equal(back.logodds, grid.logodds) and np.array_equal(back.known, grid.known)
    assert back.config == grid.config


def test_load_errors_are_one_line(tmp_path) -> None:
    with pytest.raises(InputError, match="no map.npz"):
        OccupancyGrid.load(tmp_path)
    grid = OccupancyGrid()
    grid.mark_free_disc(0, 0, 0.5)
    grid.save(tmp_path)
    # a version-1 map (metadata only in map.json) still loads; a malformed one is one line
    with np.load(tmp_path / "map.npz") as z:
        arrays = {k: z[k] for k in z.files if k != "meta"}
    np.savez(tmp_path / "map.npz", **arrays)
    meta = json.loads((tmp_path / "map.json").read_text()) | {"version": 1}
    (tmp_path / "map.json").write_text(json.dumps(meta))
    assert np.array_equal(OccupancyGrid.load(tmp_path).free, grid.free)
    (tmp_path / "map.json").write_text('{"version": 1, "resolution": 0.25}')
    with pytest.raises(InputError, match="malformed"):
        OccupancyGrid.load(tmp_path)


def test_a_floor_height_jump_becomes_a_ledge_the_robot_will_not_cross() -> None:
    # A 1 m step down 3 m ahead: the camera sees the upper floor up to the rim and the lower
    # floor from 6 m on (the pit's wall faces away, the floor right below the rim is hidden).
    v = np.arange(INTR.height, dtype=np.float64)[:, None] + 0.5
    down = (v - INTR.cy) / INTR.fy
    with np.errstate(divide="ignore"):
        upper = np.where(down > 0, CAM_H / down, np.inf)
        lower = np.where(down > 0, (CAM_H + 1.0) / down, np.inf)
    d = np.where(upper <= 3.0, upper, lower)
    d = np.where(np.isfinite(d) & (d <= 9.0), d, 0.0)
    depth = np.repeat(d, INTR.width, axis=1).astype(np.float32)
    grid = OccupancyGrid(MapConfig(resolution=0.2, step_height=0.3, obstacle_max=1.5, stride=2))
    grid.integrate(depth, Pose(0.0, 0.0, CAM_H, 0.0), INTR, CAM_H)
    near, far = grid.world_to_cell(2.0, 0.0), grid.world_to_cell(7.0, 0.0)
    assert grid.elevation[near] == pytest.approx(0.0, abs=0.1)
    lower_row = grid.elevation[far[0], far[1] - 3 : far[1] + 4]  # rows sample the far floor sparsely
    assert np.isfinite(lower_row).sum() >= 2 and np.nanmax(np.abs(lower_row + 1.0)) < 0.1
    assert not grid.ledges().any()  # nothing seen side by side yet: the camera cannot tell
    # The robot drives on and falls: its footprint on the lower floor sits next to upper floor.
    grid.mark_free_disc(3.5, 0.0, 0.5, floor_z=-1.0)
    ledge = grid.ledges()
    r, c = grid.world_to_cell(3.1, 0.0)
    assert ledge[r, c - 2 : c + 3].any() and not ledge[near]
    assert grid.free[near] and grid.free[grid.world_to_cell(3.5, 0.0)]
    trav = grid.traversable(0.25)
    assert trav[near] and not trav[r, c - 2 : c + 2].any()  # within 0.25 m of the rim
    c = c - 2 + int(np.argmax(ledge[r, c - 2 : c + 3]))
    rows, cols = np.array([near[0], r]), np.array([near[1], c])
    assert grid.blocked_at(rows, cols).tolist() == [False, True]
    # stairs: 0.2 m per tread is below step_height, no ledge
    stairs = OccupancyGrid(MapConfig(resolution=0.2, step_height=0.3))
    for i in range(5):
        stairs.mark_free_disc(0.4 * i, 0.0, 0.2, floor_z=-0.2 * i)
    assert not stairs.ledges().any()
