"""A simple waypoint controller any `Environment` can be driven with: turn towards the next
waypoint, move when roughly facing it, slow down before the last one. It reads the pose back
every tick, so momentum and sliding along walls in the simulator are corrected for."""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass, field

from .base import Environment, Observation


def wrap(a: float) -> float:
    """Angle to (-pi, pi]."""
    return math.atan2(math.sin(a), math.cos(a))


@dataclass
class ControlConfig:
    max_turn: float = math.radians(30.0)  # per tick
    drive_cone: float = math.radians(35.0)  # move only when facing the waypoint this well
    waypoint_tol: float = 0.5  # metres, intermediate waypoints
    goal_tol: float = 0.35  # metres, last waypoint
    slow_radius: float = 1.5  # start slowing down this far from the last waypoint
    stuck_ticks: int = 25  # no progress for this many ticks = stuck
    stuck_dist: float = 0.15


def command(
    obs: Observation, target: tuple[float, float], final: bool, cfg: ControlConfig
) -> tuple[float, float]:
    """(forward, turn) for one tick towards `target`."""
    dx, dy = target[0] - obs.pose.x, target[1] - obs.pose.y
    err = wrap(math.atan2(dy, dx) - obs.pose.yaw)
    turn = max(-cfg.max_turn, min(cfg.max_turn, err))
    if abs(err) > cfg.drive_cone:
        return 0.0, turn
    dist = math.hypot(dx, dy)
    speed = math.cos(err)
    if final:
        speed *= min(1.0, max(0.15, dist / cfg.slow_radius))
    return speed, turn


@dataclass
class DriveResult:
    """How a drive along waypoints ended: `reached`, or why not (`stuck`, `budget`, `stopped`)."""

    reached: bool
    reason: str
    steps: int
    distance_m: float
    last: Observation
    trajectory: list[tuple[float, float]] = field(default_factory=list)


def follow_waypoints(
    env: Environment,
    waypoints: list[tuple[float, float]],
    max_steps: int,
    on_step: Callable[[Observation], bool] | None = None,
    cfg: ControlConfig | None = None,
    start: Observation | None = None,
) -> DriveResult:
    """Drive through `waypoints` in order. `on_step` sees every observation; returning True
    stops the drive early (e.g. the explorer wants to replan)."""
    cfg = cfg or ControlConfig()
    obs = start if start is not None else env.observe()
    traj = [(obs.pose.x, obs.pose.y)]
    dist = 0.0
    i, steps = 0, 0
    anchor, anchor_step = (obs.pose.x, obs.pose.y), 0
    while i < len(waypoints):
        final = i == len(waypoints) - 1
        wx, wy = waypoints[i]
        if math.hypot(wx - obs.pose.x, wy - obs.pose.y) <= (cfg.goal_tol if final else cfg.waypoint_tol):
            i += 1
            continue
        if steps >= max_steps:
            return DriveResult(False, "budget", steps, dist, obs, traj)
        fwd, turn = command(obs, (wx, wy), final, cfg)
        prev = obs
        obs = env.step(fwd, turn)
        steps += 1
        dist += math.hypot(obs.pose.x - prev.pose.x, obs.pose.y - prev.pose.y)
        traj.append((obs.pose.x, obs.pose.y))
        if on_step is not None and on_step(obs):
            return DriveResult(False, "stopped", steps, dist, obs, traj)
        if math.hypot(obs.pose.x - anchor[0], obs.pose.y - anchor[1]) > cfg.stuck_dist:
            anchor, anchor_step = (obs.pose.x, obs.pose.y), steps
        elif steps - anchor_step >= cfg.stuck_ticks:
            return DriveResult(False, "stuck", steps, dist, obs, traj)
    return DriveResult(True, "reached", steps, dist, obs, traj)


def turn_in_place(
    env: Environment,
    angle: float,
    on_step: Callable[[Observation], bool] | None = None,
    cfg: ControlConfig | None = None,
) -> Observation:
    """Rotate by `angle` radians in ticks of at most `max_turn` (used to look around)."""
    cfg = cfg or ControlConfig()
    obs = env.observe()
    n = max(1, math.ceil(abs(angle) / cfg.max_turn))
    for _ in range(n):
        obs = env.step(0.0, angle / n)
        if on_step is not None and on_step(obs):
            break
    return obs
