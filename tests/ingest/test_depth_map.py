"""Real RGB-D in TUM layout, made by the simulator (ViZDoom renders RGB, metric depth and the
ground truth), ingested by the real `ravenmem ingest` command: the map it builds has the
simulator's walls where they are, free floor where the robot drove, and `ravenmem navigate`
plans around walls. Ground truth (walls, objects) is only used to check the map."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("vizdoom")

from functools import partial

from ravenmem.nav import load_map  # noqa: E402
from ravenmem.nav.goals import read_pose_stamped  # noqa: E402
from tests.cli.helpers import run_cli

REPO = Path(__file__).resolve().parents[2]
ENV = "vizdoom:freedoom2/MAP01"


rm = partial(run_cli, timeout=600)


def seg_dist(p: np.ndarray, segs: np.ndarray) -> np.ndarray:
    x1, y1, x2, y2 = segs.T
    ex, ey = x2 - x1, y2 - y1
    t = np.clip(((p[:, :1] - x1) * ex + (p[:, 1:] - y1) * ey) / np.maximum(ex * ex + ey * ey, 1e-12), 0, 1)
    return np.hypot(p[:, :1] - (x1 + t * ex), p[:, 1:] - (y1 + t * ey)).min(axis=1)


def crosses(a: np.ndarray, b: np.ndarray, segs: np.ndarray) -> bool:
    """Whether segment a-b properly crosses any of the segments."""
    x1, y1, x2, y2 = segs.T

    def side(ax, ay, bx, by, cx, cy):  # type: ignore[no-untyped-def]
        return (bx - ax) * (cy - ay) - (by - ay) * (cx - ax)

    o1, o2 = side(*a, *b, x1, y1), side(*a, *b, x2, y2)
    o3, o4 = side(x1, y1, x2, y2, *a), side(x1, y1, x2, y2, *b)
    return bool(np.any((o1 * o2 < 0) & (o3 * o4 < 0)))


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> dict:
    from ravenmem.robot.record import record_tum
    from ravenmem.sim import create_env

    root = tmp_path_factory.mktemp("rgbd")
    env = create_env(ENV, start_time=1.7e9)
    try:
        truth = record_tum(env, root / "rec", steps=300)
        walls = env.wall_segments()  # solid lines only
        all_lines = env.wall_segments(solid_only=False)
    finally:
        env.close()
    cam = truth["camera"]
    mem = root / "rec.mem"
    r = rm(
        "ingest",
        str(root / "rec"),
        "--memory",
        str(mem),
        "--stride",
        "25",
        "--no-ocr",
        "--intrinsics",
        f"{cam['fx']},{cam['fy']},{cam['cx']},{cam['cy']}",
        "--json",
        cwd=root,
    )
    assert r.returncode == 0, r.stderr
    return {
        "root": root,
        "mem": mem,
        "truth": truth,
        "walls": walls,
        "lines": all_lines,
        "ingest": json.loads(r.stdout),
    }


def test_tum_layout_is_the_benchmarks(recorded: dict) -> None:
    rec = recorded["root"] / "rec"
    rows = [ln.split() for ln in (rec / "depth.txt").read_text().splitlines() if not ln.startswith("#")]
    assert len(rows) == recorded["truth"]["frames"] > 200
    from PIL import Image

    with Image.open(rec / rows[10][1]) as im:
        assert im.mode in ("I;16", "I") and im.size == (320, 240)
    gt = np.loadtxt(rec / "groundtruth.txt")
    assert gt.shape == (len(rows), 8)
    assert np.allclose(np.linalg.norm(gt[:, 4:8], axis=1), 1.0)


def test_every_depth_frame_is_mapped_not_only_keyframes(recorded: dict) -> None:
    rep = recorded["ingest"]
    assert rep["kept"] <= 12  # --stride 25: a few keyframes ...
    assert rep["map"]["frames_mapped"] == recorded["truth"]["frames"]  # ... every depth frame mapped
    assert rep["map"]["cell_size_m"] == 0.05 and rep["map"]["occupied"] > 500


def test_map_command_counts_draws_and_finds_the_floor(recorded: dict) -> None:
    png = recorded["root"] / "map.png"
    r = rm("map", "--memory", str(recorded["mem"]), "--out", str(png), "--json")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    grid = load_map(recorded["mem"])
    assert out["cell_size_m"] == 0.05
    assert (out["free"], out["occupied"], out["unknown"]) == (
        int(grid.free.sum()),
        int(grid.occupied.sum()),
        int(grid.unknown.sum()),
    )
    assert out["free"] + out["occupied"] + out["unknown"] == grid.shape[0] * grid.shape[1]
    assert png.stat().st_size > 30_000
    # Doom's floor is z = 0 and up is +z: found from the depth, not assumed
    fr = grid.frame
    assert fr.method == "floor-plane fit" and fr.is_world_xy
    assert np.degrees(np.arccos(fr.up[2])) < 1.0 and abs(fr.floor) < 0.05
    recorded["counts"] = out


def test_walls_are_occupied_where_the_simulator_has_them(recorded: dict) -> None:
    from scipy import ndimage

    grid = load_map(recorded["mem"])
    traj = np.asarray(recorded["truth"]["trajectory"])
    pts = []
    for x1, y1, x2, y2 in recorded["walls"]:
        s = np.linspace(0.0, 1.0, max(2, int(math.hypot(x2 - x1, y2 - y1) / 0.1)))
        pts.append(np.stack([x1 + s * (x2 - x1), y1 + s * (y2 - y1)], 1))
    wall = np.concatenate(pts)
    near = np.min(np.hypot(wall[:, None, 0] - traj[None, ::5, 0], wall[:, None, 1] - traj[None, ::5, 1]), 1)
    wall = wall[near < 2.0]  # wall points the robot passed within 2 m of
    to_occ = ndimage.distance_transform_edt(~grid.occupied) * grid.resolution
    d = np.array([to_occ[grid.world_to_cell(x, y)] for x, y in wall])
    assert wall.shape[0] > 100 and np.mean(d <= 0.2) > 0.85
    # and obstacles are real: most occupied cells lie on a map line or at an object
    rr, cc = np.nonzero(grid.occupied)
    centres = np.stack([grid.origin[0] + (cc + 0.5) * 0.05, grid.origin[1] + (rr + 0.5) * 0.05], 1)
    objs = np.array([(o["x"], o["y"]) for o in recorded["truth"]["objects"]])
    on_obj = np.min(np.hypot(centres[:, :1] - objs[:, 0], centres[:, 1:] - objs[:, 1]), axis=1) <= 0.6
    assert np.mean((seg_dist(centres, recorded["lines"]) <= 0.3) | on_obj) > 0.8


def test_floor_where_the_robot_drove_is_free(recorded: dict) -> None:
    from ravenmem.sim.groundtruth import reachable_floor

    grid = load_map(recorded["mem"])
    traj = np.asarray(recorded["truth"]["trajectory"])
    trav = grid.traversable(grid.config.robot_radius)
    on_path = [trav[grid.world_to_cell(x, y)] for x, y in traj]
    assert np.mean(on_path) > 0.95  # no false obstacle within the robot radius of its path
    # floor the camera looked over (ray casting, not just the footprint): true reachable floor
    # within 2 m of the path, away from walls, is mostly free in the map
    truth = reachable_floor(recorded["walls"], tuple(traj[0]), 0.1)
    rr, cc = np.nonzero(truth.mask)
    fc = np.stack([truth.origin[0] + (cc + 0.5) * 0.1, truth.origin[1] + (rr + 0.5) * 0.1], 1)
    near = np.min(np.hypot(fc[:, None, 0] - traj[None, ::10, 0], fc[:, None, 1] - traj[None, ::10, 1]), 1)
    fc = fc[(near > 0.6) & (near < 2.0) & (seg_dist(fc, recorded["lines"]) > 0.3)]
    assert fc.shape[0] > 500 and np.mean([grid.free[grid.world_to_cell(x, y)] for x, y in fc]) > 0.6


def test_navigate_goes_around_a_wall(recorded: dict) -> None:
    traj = np.asarray(recorded["truth"]["trajectory"])[::5]
    walls = recorded["walls"]
    pairs = [
        (math.dist(a, b), a, b)
        for i, a in enumerate(traj)
        for b in traj[i + 1 :]
        if crosses(a, b, walls)  # the straight line between two visited places hits a wall
    ]
    assert pairs, "the recording should pass on both sides of some wall"
    straight, a, b = max(pairs, key=lambda p: p[0])
    r = rm(
        "navigate",
        "--memory",
        str(recorded["mem"]),
        "--from",
        f"{a[0]},{a[1]}",
        "--to",
        f"{b[0]},{b[1]}",
        "--json",
    )
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["ok"] and out["path_length_m"] > straight + 0.2
    wp = np.asarray(out["waypoints"])
    assert np.allclose(wp[0], a) and math.dist(wp[-1], b) < 0.2
    assert not any(crosses(p, q, walls) for p, q in zip(wp, wp[1:]))  # around the wall, not through
    # the goal as a Nav2 PoseStamped in the map frame, heading along the last leg
    x, y, yaw, frame = read_pose_stamped(out["pose_stamped"])
    assert frame == "map" and (x, y) == pytest.approx(tuple(wp[-1]))
    assert yaw == pytest.approx(math.atan2(wp[-1][1] - wp[-2][1], wp[-1][0] - wp[-2][0]), abs=1e-6)


def test_unreachable_goal_fails_with_one_line(recorded: dict) -> None:
    r = rm("navigate", "--memory", str(recorded["mem"]), "--to", "500,500")
    assert r.returncode == 1 and r.stdout == ""
    assert "unreachable" in r.stderr and "the goal is the problem" in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1
    r = rm("navigate", "--memory", str(recorded["mem"]), "--to", "500,500", "--json")  # JSON in every case
    out = json.loads(r.stdout)
    assert r.returncode == 1 and not out["ok"] and out["problem"] == "goal" and "unreachable" in out["reason"]
