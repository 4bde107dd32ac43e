"""The two phases as functions: explore an environment into a memory folder (Phase I), and
answer a query then drive there with A* on the saved map, without exploring again (Phase II).
The CLI and the demo are thin layers over these."""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError
from ..fsio import atomic_write_json
from ..memory.folder import EXPLORE
from ..nav.base import PlanResult
from ..nav.grid import OccupancyGrid
from ..nav.planning import plan_path
from ..sim.base import Environment, Observation
from ..sim.control import ControlConfig, follow_waypoints
from .explore import ExploreConfig, Explorer, ExploreReport


def coverage_reference(env: Environment, resolution: float) -> Callable[[OccupancyGrid], float] | None:
    """Ground-truth coverage measure when the backend exposes its walls (simulators do)."""
    segs = getattr(env, "wall_segments", None)
    if segs is None:
        return None
    from ..sim.groundtruth import reachable_floor

    obs = env.observe()
    truth = reachable_floor(segs(), (obs.pose.x, obs.pose.y), resolution)
    return truth.coverage


def explore_into(
    env: Environment,
    mem: Any,
    cfg: ExploreConfig | None = None,
    progress: Callable[[str], None] | None = None,
) -> tuple[OccupancyGrid, ExploreReport]:
    """Phase I: reset, explore, fill `mem`, then save the map and `explore.json` into `mem.path`."""
    cfg = cfg or ExploreConfig()
    claim = getattr(mem, "claim_map", None)
    if claim is not None:  # a simulator's poses are its world's (REP 105 map) unless it says otherwise
        claim(env.name, getattr(env, "frame_id", "map"), given=False, what=f"exploring {env.name}")
    env.reset()
    explorer = Explorer(
        env, mem, cfg, coverage_ref=coverage_reference(env, cfg.resolution), progress=progress
    )
    report = explorer.run(reset=False)
    folder = Path(mem.path)
    explorer.grid.trajectory = np.asarray(report.trajectory, np.float32).reshape(-1, 2)
    explorer.grid.meta = {"kind": "explored", "env": env.name}
    explorer.grid.save(folder)
    meta = {"env": env.name, "robot": env.robot.__dict__, "config": cfg.__dict__, "report": report.as_dict()}
    atomic_write_json(folder / EXPLORE, meta)
    return explorer.grid, report


def load_exploration(folder: str | Path) -> dict[str, Any]:
    """The `explore.json` written by Phase I (environment name, robot, trajectory, coverage)."""
    p = Path(folder) / EXPLORE
    if not p.is_file():
        raise InputError(f"{folder}: no {EXPLORE}; build this memory with `ravenmem explore` first")
    try:
        meta = json.loads(p.read_text())
        meta["env"]  # noqa: B018 - required key
    except (ValueError, KeyError, TypeError) as e:
        raise InputError(f"{p}: malformed exploration record ({e})") from e
    return meta


@dataclass
class NavOutcome:
    """How a drive to a goal went: the first plan (its length is the reported path length),
    whether the goal was reached, and the driven distance and trajectory."""

    reached: bool
    reason: str
    plan: PlanResult | None
    last: Observation
    steps: int = 0
    driven_m: float = 0.0
    trajectory: list[tuple[float, float]] = field(default_factory=list)
    paths: list[list[tuple[float, float]]] = field(default_factory=list)


def navigate_to(
    env: Environment,
    grid: OccupancyGrid,
    goal: tuple[float, float],
    max_steps: int = 800,
    attempts: int = 3,
    start: Observation | None = None,
    snap_radius: float = 4.0,
) -> NavOutcome:
    """Plan with A* on `grid` and drive there. A bump (the robot stops moving) is written into
    the map as an obstacle and the path replanned, up to `attempts` plans."""
    obs = start if start is not None else env.observe()
    out = NavOutcome(False, "", None, obs, trajectory=[(obs.pose.x, obs.pose.y)])
    radius = env.robot.radius
    for _ in range(max(1, attempts)):
        # where the robot stands is free floor, whatever the map said (it may have slid there)
        floor = obs.floor_z if obs.floor_z is not None else obs.pose.z - env.robot.camera_height
        grid.mark_free_disc(obs.pose.x, obs.pose.y, radius, floor)
        plan = plan_path(grid, (obs.pose.x, obs.pose.y), goal, radius, snap_radius=snap_radius)
        if not plan.ok:
            out.reason = plan.reason
            out.plan = out.plan or plan
            return out
        out.plan = out.plan or plan
        out.paths.append(plan.waypoints)
        res = follow_waypoints(env, plan.waypoints, max_steps - out.steps, cfg=ControlConfig(), start=obs)
        obs = res.last
        out.steps += res.steps
        out.driven_m += res.distance_m
        out.trajectory += res.trajectory[1:]
        out.last = obs
        if res.reached:
            out.reached, out.reason = True, "reached"
            return out
        out.reason = res.reason
        if res.reason != "stuck" or out.steps >= max_steps:
            return out
        nxt = next(
            (w for w in plan.waypoints[1:] if math.dist(w, (obs.pose.x, obs.pose.y)) > 0.3),
            plan.waypoints[-1],
        )
        grid.mark_blocked(
            obs.pose.x,
            obs.pose.y,
            math.atan2(nxt[1] - obs.pose.y, nxt[0] - obs.pose.x),
            radius + grid.resolution,
        )
    return out
