"""From an answer to a goal the robot can drive to: a planned path on the memory's own map and
a goal pose (position and heading) in the map frame.

The goal is where the camera was when it saw the thing asked about (the answer's position),
facing the way the camera looked then, so that on arrival the robot sees it again. The heading:
1. the model's own yaw (`yaw_source == "model"`) when the map's x, y are the world's x, y (a
   z-up robot or simulator): the model chose it, and a yaw about world z is a map heading;
2. else the evidence memory's viewing direction on the map, from its full orientation and the
   map's camera mount (a hand-held camera's yaw about world z is not where it looked; on a map
   whose up is not world z, a model's yaw cannot be placed either, and a note says so);
3. else the answer's yaw; else map +x, with a note.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from ..memory import Memory
from ..types import Pose
from .base import PlanResult
from .grid import OccupancyGrid
from .mapping import BODY, camera_matrix
from .nav2 import pose_stamped
from .planning import plan_path


class EvidenceLike(Protocol):
    id: int


class AnswerLike(Protocol):
    """What planning needs from an answer (`ravenmem.agent.schema.Answer` has it)."""

    found: bool
    position: list[float] | None
    yaw: float | None

    @property
    def yaw_source(self) -> str: ...

    @property
    def evidence(self) -> Sequence[Any]: ...


@dataclass
class GoalPlan:
    """A plan to a goal pose. `goal` is (x, y, yaw) in the map frame (None when there is no
    goal); `plan.ok` False carries a one-line `plan.reason`."""

    plan: PlanResult
    goal: tuple[float, float, float] | None
    start: tuple[float, float] | None
    target: tuple[float, float] | None = None  # the answer's position on the map
    frame_id: str = "map"
    notes: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.plan.ok

    def pose_stamped(self, stamp: float | None = None) -> dict[str, Any] | None:
        """The goal as `geometry_msgs/PoseStamped` JSON for Nav2 (None without a goal)."""
        if self.goal is None:
            return None
        return pose_stamped(*self.goal, frame_id=self.frame_id, stamp=stamp)

    def as_dict(self) -> dict[str, Any]:
        p = self.plan
        return {
            "ok": p.ok,
            "reason": p.reason,
            "start": list(self.start) if self.start else None,
            "target": list(self.target) if self.target else None,
            "goal": list(self.goal) if self.goal else None,
            "snapped": p.snapped,
            "path_length_m": p.length_m if p.ok else None,
            "waypoints": [list(w) for w in p.waypoints],
            "frame_id": self.frame_id,
            "pose_stamped": self.pose_stamped(),
            "notes": self.notes,
        }


def to_map_xy(grid: OccupancyGrid, xyz: Sequence[float]) -> tuple[float, float]:
    """A memory position (x, y[, z]) on the map: 3-D positions go through the map frame; 2-D
    ones are taken as map x, y (the same as world x, y on z-up maps)."""
    if len(xyz) >= 3:
        p = grid.frame.to_map(np.asarray(xyz[:3], np.float64))[0]
        return (float(p[0]), float(p[1]))
    return (float(xyz[0]), float(xyz[1]))


def heading_of(grid: OccupancyGrid, pose: Pose) -> float:
    """Map yaw of the direction a memory's camera looked (its optical axis on the floor)."""
    mount = np.asarray(grid.meta["mount"], np.float64) if "mount" in grid.meta else BODY
    h = grid.frame.heading(camera_matrix(pose, mount)[:3, 2])
    return pose.yaw if h is None else h


def last_pose(grid: OccupancyGrid, mem: Memory | None) -> tuple[float, float] | None:
    """Where the robot was last: the end of the map's trajectory, else the newest memory."""
    if len(grid.trajectory):
        x, y = grid.trajectory[-1]
        return (float(x), float(y))
    if mem is not None and mem.count():
        rec = max(mem.all_records(), key=lambda r: r.t)
        return to_map_xy(grid, rec.pose.xyz)
    return None


def plan_to_pose(
    grid: OccupancyGrid,
    goal: tuple[float, float],
    start: tuple[float, float] | None,
    robot_radius: float | None = None,
    snap_radius: float = 4.0,
) -> PlanResult:
    """A* on the map from `start` to `goal` (map metres), obstacles inflated by the robot
    radius saved with the map unless given. An unknown or blocked goal is snapped to the
    nearest reachable cell that sees it, else `ok` is False with the reason."""
    if start is None:
        return PlanResult(ok=False, reason="no start: give one (the map has no trajectory)", requested=goal)
    radius = grid.config.robot_radius if robot_radius is None else float(robot_radius)
    return plan_path(grid, start, goal, radius, snap_radius=snap_radius)


def plan_to_answer(
    mem: Memory | str | Path,
    answer: AnswerLike,
    start: tuple[float, float] | None = None,
    robot_radius: float | None = None,
    grid: OccupancyGrid | None = None,
    snap_radius: float = 4.0,
) -> GoalPlan:
    """Plan from the robot's last pose (or `start`, map x, y) to an answer's position and
    heading on the memory's own map.

    Never raises for an answer that cannot be driven to (not found, no position, unreachable):
    `plan.ok` is False and `plan.reason` says why in one line. Raises InputError only when the
    memory has no map.
    """
    m = mem if isinstance(mem, Memory) else None
    folder = mem.path if isinstance(mem, Memory) else Path(mem)
    grid = grid if grid is not None else OccupancyGrid.load(folder)
    if start is None:
        start = last_pose(grid, m)
    notes: list[str] = []
    if not answer.found or not answer.position:
        reason = "the answer has no position to go to" + ("" if answer.found else " (not found)")
        return GoalPlan(PlanResult(ok=False, reason=reason), None, start)
    if len(answer.position) < 2 or not all(math.isfinite(float(v)) for v in answer.position):
        return GoalPlan(PlanResult(ok=False, reason=f"bad answer position {answer.position!r}"), None, start)
    target = to_map_xy(grid, [float(v) for v in answer.position])
    yaw = answer.yaw
    from_model = yaw is not None and answer.yaw_source == "model"
    pose = None if from_model and grid.frame.is_world_xy else _evidence_pose(m, answer)
    if pose is not None:
        yaw = heading_of(grid, pose)
        if from_model:
            notes.append(
                "the model's yaw is about world z, which is not this map's up: the goal faces "
                "where the evidence camera looked"
            )
    elif yaw is None:
        yaw = 0.0
        notes.append("no heading in the answer: the goal faces map +x")
    plan = plan_to_pose(grid, target, start, robot_radius, snap_radius)
    if not plan.ok:
        return GoalPlan(plan, None, start, target, notes=notes)
    assert plan.goal is not None
    if plan.snapped:
        notes.append(f"goal moved {math.dist(plan.goal, target):.2f} m to a reachable cell")
    return GoalPlan(plan, (plan.goal[0], plan.goal[1], float(yaw)), start, target, notes=notes)


def _evidence_pose(mem: Memory | None, answer: AnswerLike) -> Pose | None:
    """The full pose of the answer's first evidence memory, when the memory is at hand."""
    if mem is None or not answer.evidence:
        return None
    ev_id = getattr(answer.evidence[0], "id", None)
    if ev_id is None:
        return None
    try:
        (rec,) = mem.get([int(ev_id)])
    except ValueError:  # not an id, or no such memory (NotFoundError is a ValueError)
        return None
    return rec.pose
