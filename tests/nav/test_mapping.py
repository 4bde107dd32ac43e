"""Maps from depth frames: floor fit, ray casting, obstacles, saving and extending (synthetic depth)."""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parent))

from depthscene import INTR, look, pose_of, render  # noqa: E402

from ravenmem.errors import InputError  # noqa: E402
from ravenmem.nav import load_map  # noqa: E402
from ravenmem.nav.frame import MapFrame  # noqa: E402
from ravenmem.nav.grid import OccupancyGrid  # noqa: E402
from ravenmem.nav.mapping import (  # noqa: E402
    SKIP_DONE,
    MapBuilder,
    back_project,
    fit_floor,
    integrate_points,
    recording_config,
)
from ravenmem.types import Frame  # noqa: E402

BOX = (2.0, -0.5, 2.6, 0.5, 0.8)  # x 2..2.6, y -0.5..0.5, 0.8 m tall
# A TUM-like world: up is world +y, and the scene's x, y lie along world z, x.
WORLD_Y_UP = np.array([[0, 1, 0, 0], [0, 0, 1, 0], [1, 0, 0, 0], [0, 0, 0, 1]], float)


def _frames(world_from_scene: np.ndarray, n: int = 12, t0: float = 100.0, source: str = "rec") -> list[Frame]:
    """A camera at 1.2 m walking along x towards the box, looking at it, pitched 20 degrees down."""
    out = []
    for i in range(n):
        x = -1.0 + 1.2 * i / max(1, n - 1)
        yaw = 0.25 * math.sin(i)
        cam = look(x, 0.1 * math.cos(i), 1.2, yaw, math.radians(20))
        depth = render(cam, [BOX])
        out.append(
            Frame(
                image=np.zeros((2, 2, 3), np.uint8),
                t=t0 + i,
                pose=pose_of(world_from_scene @ cam),
                source=source,
                index=i,
                depth=depth,
            )
        )
    return out


def test_back_project_inverts_the_pinhole() -> None:
    depth = np.zeros((240, 320), np.float32)
    depth[120, 260] = 2.0  # pixel centre (260.5, 120.5)
    pts = back_project(depth, INTR, 1, 0.1, 5.0)
    assert pts.shape == (1, 3)
    assert pts[0] == pytest.approx([(260.5 - 160) / 200 * 2, 0.5 / 200 * 2, 2.0])


@pytest.mark.parametrize("world", [np.eye(4), WORLD_Y_UP], ids=["z-up", "y-up (TUM-like)"])
def test_floor_fit_finds_the_floor_under_a_pitched_camera(world: np.ndarray) -> None:
    # the box top (0.8 m) holds many points too; the floor is the lowest strong band
    cams = [look(-1.0 + 0.2 * i, 0.0, 1.2, 0.1 * i, math.radians(25)) for i in range(6)]
    pts, ups = [], []
    for c in cams:
        wc = world @ c
        local = back_project(render(c, [(1.0, -1.0, 3.0, 1.0, 0.8)]), INTR, 4, 0.1, 6.0)
        pts.append(local @ wc[:3, :3].T + wc[:3, 3])
        ups.append(-wc[:3, 1])
    fr = fit_floor(np.concatenate(pts), np.stack([(world @ c)[:3, 3] for c in cams]), np.stack(ups))
    true_up = world[:3, 2]
    assert fr.method == "floor-plane fit"
    assert math.degrees(math.acos(float(np.dot(fr.up, true_up)))) < 0.5
    assert fr.floor == pytest.approx(float(world[:3, 3] @ true_up), abs=0.01)
    # map axes are the world's own (snapped), right-handed with up
    a, b = np.asarray(fr.axes)
    assert np.allclose(np.cross(a, b), true_up, atol=1e-9)
    if np.allclose(world, np.eye(4)):
        assert fr.is_world_xy


def test_floor_not_seen_falls_back_to_the_lowest_points() -> None:
    cam = look(0.0, 0.0, 1.2, 0.0, 0.0)
    pts = np.random.default_rng(0).uniform([1.0, -1.0, 0.5], [2.0, 1.0, 2.0], (500, 3))  # a wall, no floor
    fr = fit_floor(pts, cam[None, :3, 3], -cam[None, :3, 1])
    assert fr.method.startswith("lowest points") and fr.floor == pytest.approx(0.5, abs=0.05)
    with pytest.raises(InputError, match="too few"):
        fit_floor(pts[:10], cam[None, :3, 3], -cam[None, :3, 1])


def test_one_frame_ray_casting_wall_free_before_unknown_behind() -> None:
    grid = OccupancyGrid(recording_config(resolution=0.1))
    grid.meta = {"kind": "recorded", "frame": MapFrame().as_dict()}
    cam = look(0.0, 0.0, 1.0, 0.0, math.radians(15))
    wall = (3.0, -5.0, 3.2, 5.0, 2.5)
    local = back_project(render(cam, [wall]), INTR, 2, 0.1, 8.0)
    n = integrate_points(grid, local @ cam[:3, :3].T + cam[:3, 3], cam[:3, 3])
    assert n > 5

    def state(x: float, y: float) -> str:
        c = grid.world_to_cell(x, y)
        if not grid.contains(c) or not grid.known[c]:
            return "unknown"
        return "occupied" if grid.occupied[c] else "free"

    for y in (-0.5, 0.0, 0.5):
        assert state(3.05, y) == "occupied"
        for x in (1.0, 2.0, 2.8):
            assert state(x, y) == "free", (x, y)
        assert state(4.0, y) == "unknown"  # behind the wall
    assert state(-2.0, 0.0) == "unknown"  # behind the camera
    assert grid.free[grid.world_to_cell(0.0, 0.0)]  # under the camera


@pytest.mark.parametrize("world", [np.eye(4), WORLD_Y_UP], ids=["z-up", "y-up (TUM-like)"])
def test_builder_maps_a_box_saves_and_extends(tmp_path: Path, world: np.ndarray) -> None:
    frames = _frames(world)
    b = MapBuilder(tmp_path, INTR, "optical", recording_config(resolution=0.05), fit_frames=5, save_every=4)
    assert all(b.add(f) for f in frames)
    b.close()
    grid = load_map(tmp_path)
    assert grid.kind == "recorded" and grid.frame.method == "floor-plane fit"
    # map coordinates of scene points: the box's centre and the floor in front of it
    to_map = lambda x, y: tuple(grid.frame.to_map((world @ np.array([x, y, 0.0, 1.0]))[:3])[0])  # noqa: E731
    for y in (-0.4, 0.0, 0.4):  # the box's face towards the camera
        assert grid.occupied[grid.world_to_cell(*to_map(2.02, y))], y
    for x in (0.5, 1.0, 1.6):
        assert grid.free[grid.world_to_cell(*to_map(x, 0.0))], x
    assert grid.unknown[grid.world_to_cell(*to_map(3.5, 0.0))]  # hidden behind the box
    assert len(grid.trajectory) >= 10
    if np.allclose(world, np.eye(4)):  # z-up: map x, y are world x, y
        assert to_map(2.1, 0.3) == pytest.approx((2.1, 0.3))
    # a second builder (a second ingest) skips frames already in the map and adds new ones
    b2 = MapBuilder(tmp_path, INTR, "optical")
    assert not any(b2.add(f) for f in frames)
    assert b2.stats.skipped == {SKIP_DONE: len(frames)}
    later = _frames(world, n=4, t0=200.0)
    assert all(b2.add(f) for f in later)
    b2.close()
    assert load_map(tmp_path).meta["sources"]["rec"] == 203.0
    assert not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]


def test_builder_without_camera_counts_and_maps_nothing(tmp_path: Path) -> None:
    b = MapBuilder(tmp_path, None)
    assert not b.add(_frames(np.eye(4), n=1)[0])
    b.close()
    assert b.summary()["skipped"] == {"no camera intrinsics": 1}
    assert not (tmp_path / "map.npz").exists()


def test_a_damaged_map_is_one_line(tmp_path: Path) -> None:
    with pytest.raises(InputError, match="no map.npz"):
        load_map(tmp_path)
    (tmp_path / "map.npz").write_bytes(b"not a zip")
    with pytest.raises(InputError, match="unreadable map"):
        load_map(tmp_path)
