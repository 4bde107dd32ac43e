"""Navigation speed: depth integration, A*, Dijkstra field, frontier search, exploration steps/s.

    PYTHONPATH=src python benchmarks/bench_nav.py [--vizdoom]
Prints one line per measurement (median of repeats); numbers go into docs/measured.md and docs/navigation.md.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import numpy as np

from ravenmem.nav import MapConfig, OccupancyGrid, astar, distance_field, find_frontiers
from ravenmem.robot.explore import ExploreConfig, Explorer
from ravenmem.sim import create_env
from ravenmem.types import Intrinsics, Pose


def timed(fn: Callable[[], object], repeat: int = 5) -> float:
    ts = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return statistics.median(ts)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--vizdoom", action="store_true", help="also time a ViZDoom exploration")
    args = ap.parse_args()
    rng = np.random.default_rng(0)

    intr = Intrinsics.from_fov(320, 240, 90.0)
    depth = rng.uniform(0.5, 9.0, (240, 320)).astype(np.float32)
    grid = OccupancyGrid(MapConfig(resolution=0.25))
    t = timed(lambda: grid.integrate(depth, Pose(0, 0, 1.28, 0.3), intr, 1.28), 20)
    print(f"integrate 320x240 depth (stride 4): {1000 * t:.1f} ms")

    # recorded RGB-D: one 640x480 Kinect-like frame (a floor, a wall 3 m ahead, a box) through
    # the 6-DoF mapper (back-projection, floor heights, ray casting to every target cell)
    from ravenmem.nav.frame import MapFrame
    from ravenmem.nav.mapping import back_project, camera_matrix, integrate_points, recording_config
    from ravenmem.types import Intrinsics as Cam

    kin = Cam(525.0, 525.0, 319.5, 239.5, 640, 480)
    v, u = np.mgrid[0:480, 0:640].astype(np.float64) + 0.5
    pitch = np.radians(15.0)
    down = (v - kin.cy) / kin.fy  # per unit depth, camera frame
    ray_z = np.cos(pitch) * down + np.sin(pitch)  # downward component in the world per unit depth
    with np.errstate(divide="ignore"):
        floor = np.where(ray_z > 0, 1.2 / ray_z, np.inf)
    wall = 3.0 / (np.cos(pitch) - np.sin(pitch) * down)
    d_rgbd = np.where(wall > 0, np.minimum(floor, wall), floor).astype(np.float32)
    d_rgbd[~np.isfinite(d_rgbd)] = 0
    cam = camera_matrix(Pose(0.0, 0.0, 1.2, 0.0, (0.5, -0.5, 0.5, -0.5)), np.eye(4))
    for res in (0.05, 0.1):
        g = OccupancyGrid(recording_config(resolution=res))
        g.meta = {"kind": "recorded", "frame": MapFrame().as_dict()}
        cfg = g.config

        def one(g: OccupancyGrid = g, cfg: MapConfig = cfg) -> None:
            pts = back_project(d_rgbd, kin, cfg.stride, cfg.min_range, cfg.max_range)
            integrate_points(g, pts @ cam[:3, :3].T + cam[:3, 3], cam[:3, 3])

        t = timed(one, 10)
        print(
            f"recorded RGB-D 640x480 frame into a {res:g} m map (stride 4, 6-DoF, ray casting): {1000 * t:.1f} ms"
        )

    trav = rng.random((400, 400)) > 0.25
    trav[0, :] = trav[:, -1] = True  # a guaranteed route along two borders
    t = timed(lambda: astar(trav, (0, 0), (399, 399)), 3)
    cells, cost, expanded = astar(trav, (0, 0), (399, 399))
    print(
        f"A* 400x400 random 25% blocked, corner to corner: {1000 * t:.0f} ms, {expanded} expanded, cost {cost:.1f}"
    )
    t = timed(lambda: distance_field(trav, (0, 0)), 3)
    print(f"Dijkstra distance field 400x400 (scipy): {1000 * t:.0f} ms")

    env = create_env("synthetic:rooms", start_time=0.0)
    t0 = time.perf_counter()
    rep = Explorer(env, None, ExploreConfig(steps=1000, resolution=0.2)).run()
    dt = time.perf_counter() - t0
    print(
        f"synthetic:rooms exploration: {rep.steps} steps in {dt:.1f} s ({rep.steps / dt:.0f} steps/s), "
        f"{rep.stop_reason}"
    )
    ex = Explorer(env, None, ExploreConfig(steps=300, resolution=0.2))
    ex.run()
    here = env.observe().pose
    t = timed(lambda: find_frontiers(ex.grid, (here.x, here.y), 0.25), 5)
    print(f"find_frontiers on that map ({ex.grid.shape[0]}x{ex.grid.shape[1]}): {1000 * t:.1f} ms")

    if args.vizdoom:
        env = create_env("vizdoom:freedoom2/MAP02", start_time=0.0)
        t0 = time.perf_counter()
        rep = Explorer(env, None, ExploreConfig(steps=3000)).run()
        dt = time.perf_counter() - t0
        print(
            f"vizdoom:freedoom2/MAP02 exploration (map only, no memory): {rep.steps} steps in {dt:.1f} s "
            f"({rep.steps / dt:.0f} steps/s), {rep.coverage[-1][2]:.0f} m^2, {rep.stop_reason}"
        )
        env.close()


if __name__ == "__main__":
    main()
