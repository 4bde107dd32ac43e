"""Phase I: frontier exploration of an `Environment` while building the occupancy map and the
visual memory. The robot looks around once, then repeatedly drives (A*) towards the nearest
reachable frontier, replanning as the map grows, until no reachable frontier is left or the
step budget ends. Keyframes (chosen by motion) go into the memory with their pose and time."""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import InputError
from ..nav.frontier import Frontier, find_frontiers
from ..nav.grid import MapConfig, OccupancyGrid
from ..nav.planning import plan_path
from ..progress import Eta, fmt_seconds
from ..sim.base import Environment, Observation, RobotSpec
from ..sim.control import ControlConfig, follow_waypoints, turn_in_place, wrap
from ..types import Frame, Intrinsics


def map_config(robot: RobotSpec, resolution: float = 0.25, max_range: float = 10.0) -> MapConfig:
    """The map settings for a simulated robot's body (what it can step over or pass under)."""
    return MapConfig.for_body(robot.step_height, robot.height, resolution, max_range)


def locate(obs: Observation, box: tuple[int, int, int, int], intr: Intrinsics) -> tuple[float, float] | None:
    """Where a labelled object is, from its box and the depth image: the median depth of the
    box's lowest quarter (the object's foot and the floor beside it, not the wall behind),
    along the ray through the box's centre column. None without a depth reading there."""
    x, y, w, h = box
    rows = obs.depth[max(0, y + (3 * h) // 4) : y + h, max(0, x) : x + w]
    vals = rows[np.isfinite(rows) & (rows > 0)]
    if vals.size == 0:
        return None
    d = float(np.median(vals))
    xr = (x + w / 2.0 - intr.cx) / intr.fx * d  # metres right of the optical axis
    c, s = math.cos(obs.pose.yaw), math.sin(obs.pose.yaw)
    return (obs.pose.x + d * c + xr * s, obs.pose.y + d * s - xr * c)


@dataclass
class ExploreConfig:
    """`steps` is the control-tick budget; keyframes are kept when the robot moved
    `keyframe_dist` metres or turned `keyframe_turn` radians since the last one."""

    steps: int = 3000
    resolution: float = 0.25
    replan_every: int = 15
    min_frontier: int = 4
    keyframe_dist: float = 1.0
    keyframe_turn: float = math.radians(30.0)
    batch: int = 16
    coverage_every: int = 25
    max_failures: int = 25

    def __post_init__(self) -> None:
        if self.steps < 1 or self.replan_every < 1 or self.batch < 1 or self.coverage_every < 1:
            raise InputError(f"explore: steps, replan_every, batch and coverage_every must be >= 1: {self}")
        if self.resolution <= 0 or self.keyframe_dist < 0 or self.keyframe_turn < 0:
            raise InputError(f"explore: resolution must be > 0, keyframe_dist/turn >= 0: {self}")


@dataclass
class ExploreReport:
    """What exploration did. `coverage` rows are (step, sim seconds, explored free m^2, fraction
    of the reference floor area or None); `keyframes` maps memory id -> visible object ids and
    `keyframe_labels` memory id -> {object id: (box pixels, x, y)}: the object's label box size
    and where the box and the depth image place it (ground-truth labels: for scoring and oracle
    perception only)."""

    steps: int = 0
    sim_seconds: float = 0.0
    wall_seconds: float = 0.0
    stop_reason: str = ""
    distance_m: float = 0.0
    plans: int = 0
    coverage: list[tuple[int, float, float, float | None]] = field(default_factory=list)
    trajectory: list[tuple[float, float]] = field(default_factory=list)
    keyframes: dict[int, list[int]] = field(default_factory=dict)
    keyframe_labels: dict[int, dict[int, tuple[int, float, float]]] = field(default_factory=dict)
    seen_objects: set[int] = field(default_factory=set)

    def as_dict(self) -> dict[str, Any]:
        return {
            "steps": self.steps,
            "sim_seconds": self.sim_seconds,
            "wall_seconds": self.wall_seconds,
            "stop_reason": self.stop_reason,
            "distance_m": self.distance_m,
            "plans": self.plans,
            "coverage": [list(c) for c in self.coverage],
            "trajectory": [list(p) for p in self.trajectory],
            "keyframes": {str(k): v for k, v in self.keyframes.items()},
            "keyframe_labels": {
                str(k): {str(o): list(lab) for o, lab in v.items()} for k, v in self.keyframe_labels.items()
            },
            "seen_objects": sorted(self.seen_objects),
        }


class Explorer:
    """Runs Phase I. `mem` is any object with `add_frames(list[Frame]) -> list[int]` (a
    `ravenmem.Memory`) or None to only map; `coverage_ref(grid) -> fraction` is an optional
    ground-truth coverage measure (simulators provide one)."""

    def __init__(
        self,
        env: Environment,
        mem: Any = None,
        cfg: ExploreConfig | None = None,
        grid: OccupancyGrid | None = None,
        coverage_ref: Callable[[OccupancyGrid], float] | None = None,
        progress: Callable[[str], None] | None = None,
    ) -> None:
        self.env = env
        self.mem = mem
        self.cfg = cfg or ExploreConfig()
        self.grid = grid or OccupancyGrid(map_config(env.robot, self.cfg.resolution))
        self.coverage_ref = coverage_ref
        self.progress = progress
        self.report = ExploreReport()
        self.ctrl = ControlConfig()
        self._pending: list[tuple[Frame, list[int], dict[int, tuple[int, float, float]]]] = []
        self._last_kf: Observation | None = None
        self._t_start = 0.0
        self._blacklist: list[tuple[float, float]] = []
        self._obs: Observation | None = None
        self._mark_step = 0
        self._path: tuple[np.ndarray, np.ndarray] | None = None

    # --- per observation ------------------------------------------------------------------
    def _on_obs(self, obs: Observation) -> bool:
        """Map, remember, log. Returns True when the step budget is spent."""
        r = self.report
        if self._obs is not None:
            r.distance_m += math.hypot(obs.pose.x - self._obs.pose.x, obs.pose.y - self._obs.pose.y)
        self._obs = obs
        r.steps = obs.step
        r.sim_seconds = obs.t - self._t_start
        r.trajectory.append((obs.pose.x, obs.pose.y))
        robot = self.env.robot
        cam_h = obs.camera_height if obs.camera_height is not None else robot.camera_height
        self.grid.integrate(obs.depth, obs.pose, self.env.intrinsics, cam_h)
        self.grid.mark_free_disc(obs.pose.x, obs.pose.y, robot.radius, obs.pose.z - cam_h)
        r.seen_objects.update(obs.visible)
        self._maybe_keyframe(obs)
        if obs.step % self.cfg.coverage_every == 0:
            self._log_coverage(obs)
        # the map grew an obstacle or a drop across the way: stop and replan now
        if self._path is not None and obs.step % 2 == 0 and self.grid.blocked_at(*self._path).any():
            self._path = None
            return True
        return obs.step >= self.cfg.steps

    def _maybe_keyframe(self, obs: Observation) -> None:
        last = self._last_kf
        if last is not None:
            moved = math.hypot(obs.pose.x - last.pose.x, obs.pose.y - last.pose.y) >= self.cfg.keyframe_dist
            turned = abs(wrap(obs.pose.yaw - last.pose.yaw)) >= self.cfg.keyframe_turn
            if not (moved or turned):
                return
        self._last_kf = obs
        if self.mem is None:
            return
        frame = Frame(image=obs.rgb.copy(), t=obs.t, pose=obs.pose, source=self.env.name, index=obs.step)
        labels = {}
        for oid, box in obs.visible_boxes.items():
            xy = locate(obs, box, self.env.intrinsics)
            if xy is not None:
                labels[oid] = (box[2] * box[3], xy[0], xy[1])
        self._pending.append((frame, list(obs.visible), labels))
        if len(self._pending) >= self.cfg.batch:
            self._flush()

    def _flush(self) -> None:
        if not self._pending or self.mem is None:
            return
        ids = self.mem.add_frames([f for f, _, _ in self._pending])
        for mid, (_, vis, labels) in zip(ids, self._pending):
            self.report.keyframes[int(mid)] = vis
            self.report.keyframe_labels[int(mid)] = labels
        self._pending = []

    def _log_coverage(self, obs: Observation) -> None:
        frac = self.coverage_ref(self.grid) if self.coverage_ref is not None else None
        row = (obs.step, obs.t - self._t_start, self.grid.explored_free_area(), frac)
        if not self.report.coverage or self.report.coverage[-1][0] != obs.step:
            self.report.coverage.append(row)

    # --- the loop -------------------------------------------------------------------------
    def _say(self, msg: str) -> None:
        if self.progress is not None:
            self.progress(msg)

    def _pick(self, frontiers: list[Frontier], current: tuple[float, float] | None) -> Frontier:
        """Nearest frontier, but keep the current target while it is still a frontier and not
        much farther than the nearest (stops dithering between two equally near ones)."""
        best = frontiers[0]
        if current is None:
            return best
        for f in frontiers:
            if math.dist(f.target, current) < 1.0 and f.cost_m <= best.cost_m + 3.0:
                return f
        return best

    def _stalled(self, step: int, window: int = 30, dist: float = 0.25) -> bool:
        """True when the robot has not left a small disc for `window` steps of driving."""
        tr = self.report.trajectory
        if len(tr) < window or step - self._mark_step < window:
            return False
        x, y = tr[-1]
        return all(math.hypot(px - x, py - y) < dist for px, py in tr[-window:])

    def run(self, reset: bool = True) -> ExploreReport:
        t_wall = time.perf_counter()
        # the step budget is an upper bound: exploration ends early when no frontier is left
        eta = Eta(self._say, "explore, control steps", self.cfg.steps, upper=True)
        obs = self.env.reset() if reset else self.env.observe()
        self._t_start = obs.t
        self._on_obs(obs)
        obs = turn_in_place(self.env, 2 * math.pi - 1e-3, self._on_obs, self.ctrl)
        radius = self.env.robot.radius
        current: tuple[float, float] | None = None
        failures = 0
        stop = ""
        while not stop:
            if obs.step >= self.cfg.steps:
                stop = "step budget spent"
                break
            xy = (obs.pose.x, obs.pose.y)
            frontiers = find_frontiers(
                self.grid, xy, radius, self.cfg.min_frontier, blacklist=self._blacklist
            )
            if not frontiers:
                stop = "no reachable frontier left"
                break
            f = self._pick(frontiers, current)
            plan = plan_path(self.grid, xy, f.target, radius)
            self.report.plans += 1
            if not plan.ok:
                self._blacklist.append(f.target)
                failures += 1
                if failures >= self.cfg.max_failures:
                    stop = "too many planning failures"
                continue
            current = f.target
            cells = np.asarray(plan.cells[1:] or plan.cells)
            self._path = (cells[:, 0], cells[:, 1])
            budget = min(self.cfg.replan_every, self.cfg.steps - obs.step)
            res = follow_waypoints(self.env, plan.waypoints, budget, self._on_obs, self.ctrl, start=obs)
            self._path = None
            obs = res.last
            if res.reached:
                ang = math.atan2(f.centroid[1] - obs.pose.y, f.centroid[0] - obs.pose.x)
                obs = turn_in_place(self.env, wrap(ang - obs.pose.yaw), self._on_obs, self.ctrl)
                self._blacklist.append(f.target)  # looked at it from up close: do not come back
                current = None
                failures = 0
                self._mark_step = obs.step
            elif res.reason == "stuck" or self._stalled(obs.step):
                # Driving but not moving: something the camera cannot see blocks the way.
                # Remember it as an obstacle (a bumper hit), give up this frontier, back off.
                wx, wy = plan.waypoints[min(1, len(plan.waypoints) - 1)]
                heading = math.atan2(wy - obs.pose.y, wx - obs.pose.x)
                self.grid.mark_blocked(obs.pose.x, obs.pose.y, heading, radius + self.grid.resolution)
                self._blacklist.append(f.target)
                current = None
                failures += 1
                for _ in range(4):
                    obs = self.env.step(-0.5, 0.0)
                    self._on_obs(obs)
                self._mark_step = obs.step
                if failures >= self.cfg.max_failures:
                    stop = "too many planning failures"
            else:
                failures = 0
            eta.update(
                min(obs.step, self.cfg.steps - 1),  # the last line is the stop's, below
                f"explored {self.grid.explored_free_area():.0f} m^2, {len(frontiers)} frontiers",
            )
        self._flush()
        self._log_coverage(obs)
        self._say(
            f"explore: stopped at control step {obs.step} of {self.cfg.steps} ({stop}), explored "
            f"{self.grid.explored_free_area():.0f} m^2 in {fmt_seconds(time.perf_counter() - t_wall)}"
        )
        self.report.stop_reason = stop
        self.report.wall_seconds = time.perf_counter() - t_wall
        return self.report
