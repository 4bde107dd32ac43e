"""From an answer to a goal a robot can drive to: `goal_for(answer, memory, start)`, the one goal
path of every front end (`ask --navigate`, `navigate`, `POST /ask` with `navigate`, MCP `ask`,
the Zenoh link, the ROS 2 node and the `ravenmem_msgs/srv/Ask` service).

The plan is made on the memory's own map, in the memory's own frame (REP 105: `map`, or `odom`
when the poses had no map frame); a goal is never expressed in any other frame. Step by step:

1. refuse what must not be driven to, each with a one-line reason a robot can log and the
   `problem` it names: a failed question or an answer marked unsupported (`answer`), an answer
   without a usable position (`answer`), an answer from another map (`map`: the memories were
   never aligned, see `ravenmem align`), a memory without a map (`map`);
2. put the answer's position on the map (`to_map_xy`) and plan with A* from `start` or the
   robot's latest pose; a goal in an obstacle or unknown space is snapped to the nearest
   reachable free cell that sees it; an unreachable plan says whether the start or the goal is
   the problem (a start cut off from the rest of the map by walls or one-way ledges is blamed,
   not the goal);
3. set the heading (radians, REP 103: counter-clockwise from map x): the model's own yaw when
   it gave one on a map whose up is the world's z; else, when the goal had to move, facing the
   answer's position from the goal; else the way the evidence camera looked (the goal is where
   it stood, so the robot sees the thing again); else the last leg of the path; else map +x.
   The plan records which (`heading.source`) and why (`heading.reason`).

`GoalPlan.as_dict()` is the JSON every front end returns; `GoalPlan.pose_stamped()` is the one
`geometry_msgs/PoseStamped` builder (JSON; `ravenmem.ros.msgs.to_message` makes the CDR of the
same dict for the wire).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np
from scipy import ndimage

from ..errors import InputError
from ..memory import Memory
from ..memory.folder import MAP_GRID
from ..refusal import refusal_of
from ..stamps import sec_nanosec
from ..types import Pose, yaw_of
from .base import PlanResult
from .grid import OccupancyGrid
from .mapping import BODY, camera_matrix
from .planning import plan_path, start_near

SNAP_RADIUS = 4.0  # metres a goal may move to a reachable cell that sees it

# what a refused or failed plan blames (`GoalPlan.problem`)
ANSWER, MAP, START, GOAL = "answer", "map", "start", "goal"


class AnswerLike(Protocol):
    """What planning needs from an answer (`ravenmem.agent.schema.Answer` has it). Optional
    attributes read when present: `failed`, `error`, `unsupported`, `support_distance` (an
    answer whose position rests on no memory the model saw) and `map_id` (the map its
    position is in)."""

    found: bool
    position: list[float] | None
    yaw: float | None

    @property
    def yaw_source(self) -> str: ...

    @property
    def evidence(self) -> Sequence[Any]: ...


@dataclass
class PositionGoal:
    """A goal given as a map position (`navigate --to x,y`), shaped as an answer so that it
    takes the same path as an answer's position."""

    position: list[float]
    yaw: float | None = None
    found: bool = True
    yaw_source: str = "none"
    evidence: Sequence[Any] = ()


@dataclass(frozen=True)
class Heading:
    """The goal's yaw (radians, map frame), where it came from and why."""

    yaw: float
    source: str  # model | target | evidence | path | default
    reason: str

    def as_dict(self) -> dict[str, Any]:
        return {"yaw": self.yaw, "source": self.source, "reason": self.reason}


@dataclass
class GoalPlan:
    """A plan to a goal pose in the memory's frame. `goal` is (x, y, yaw) on the map (None when
    there is no goal); when `ok` is False, `reason` says why in one line and `problem` names
    what is wrong: `answer`, `map`, `start` or `goal`."""

    plan: PlanResult
    goal: tuple[float, float, float] | None = None
    start: tuple[float, float] | None = None
    target: tuple[float, float] | None = None  # the answer's position on the map
    frame_id: str = "map"
    map_id: str | None = None
    heading: Heading | None = None
    problem: str | None = None
    notes: list[str] = field(default_factory=list)

    @property
    def ok(self) -> bool:
        return self.plan.ok

    @property
    def reason(self) -> str:
        return self.plan.reason

    def pose_stamped(self, stamp: float | None = None) -> dict[str, Any] | None:
        """The goal as `geometry_msgs/PoseStamped` JSON in the memory's frame (None without one)."""
        if self.goal is None:
            return None
        return pose_stamped(*self.goal, frame_id=self.frame_id, stamp=stamp)

    def as_dict(self) -> dict[str, Any]:
        """The plan as every front end returns it (`ravenmem ask --navigate --json`)."""
        p = self.plan
        return {
            "ok": p.ok,
            "reason": p.reason,
            "problem": self.problem,
            "frame_id": self.frame_id,
            "map_id": self.map_id,
            "start": list(self.start) if self.start else None,
            "target": list(self.target) if self.target else None,
            "goal": list(self.goal) if self.goal else None,
            "heading": self.heading.as_dict() if self.heading else None,
            "snapped": p.snapped,
            "path_length_m": p.length_m if p.ok else None,
            "waypoints": [list(w) for w in p.waypoints],
            "pose_stamped": self.pose_stamped(),
            "notes": self.notes,
        }


def pose_stamped(
    x: float, y: float, yaw: float, frame_id: str = "map", stamp: float | None = None
) -> dict[str, Any]:
    """A `geometry_msgs/msg/PoseStamped` as JSON (what `ros2 topic pub /goal_pose` takes):
    position on the map plane (z = 0), orientation a rotation of `yaw` about the map's z.
    A stamp of zero (the default) asks tf for its latest transform."""
    return {
        "header": {"stamp": sec_nanosec(0.0 if stamp is None else float(stamp)), "frame_id": frame_id},
        "pose": {
            "position": {"x": float(x), "y": float(y), "z": 0.0},
            "orientation": {"x": 0.0, "y": 0.0, "z": math.sin(yaw / 2.0), "w": math.cos(yaw / 2.0)},
        },
    }


def read_pose_stamped(msg: dict[str, Any]) -> tuple[float, float, float, str]:
    """(x, y, yaw, frame_id) from PoseStamped JSON; InputError naming the missing field."""
    try:
        p, q = msg["pose"]["position"], msg["pose"]["orientation"]
        x, y = float(p["x"]), float(p["y"])
        qx, qy, qz, qw = (float(q[k]) for k in ("x", "y", "z", "w"))
        frame = str(msg["header"]["frame_id"])
    except (KeyError, TypeError, ValueError) as e:
        raise InputError(f"not a PoseStamped: missing or bad field {e}") from None
    return x, y, yaw_of(qx, qy, qz, qw), frame


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


def goal_for(
    answer: AnswerLike,
    memory: Memory,
    start: tuple[float, float] | None = None,
    *,
    robot_radius: float | None = None,
    grid: OccupancyGrid | None = None,
    snap_radius: float = SNAP_RADIUS,
    allow_unsupported: bool = False,
) -> GoalPlan:
    """The goal for `answer` on `memory`'s map (see the module docstring): never raises for an
    answer, a map or a start that cannot be driven from or to; `ok` False carries the reason
    and the `problem`. `grid` is the memory's map when the caller loaded it already."""
    frame_id, map_id = memory.frame_id, memory.map_id
    refused = _refusal(answer, map_id, allow_unsupported)
    if refused is not None:
        return GoalPlan(
            PlanResult(ok=False, reason=refused[1]), frame_id=frame_id, map_id=map_id, problem=refused[0]
        )
    if grid is None:
        try:
            grid = OccupancyGrid.load(memory.path)
        except InputError as e:
            why = f"no map to plan on ({e})" if (memory.path / MAP_GRID).exists() else str(e)
            return GoalPlan(PlanResult(ok=False, reason=why), frame_id=frame_id, map_id=map_id, problem=MAP)
    if (memory.manifest.anchor or {}).get("transform") != grid.meta.get("anchor"):
        why = "the map is not in the frame of the memory's poses (a re-anchoring was interrupted): run `ravenmem align --apply` again"
        return GoalPlan(PlanResult(ok=False, reason=why), frame_id=frame_id, map_id=map_id, problem=MAP)
    assert answer.position is not None
    target = to_map_xy(grid, [float(v) for v in answer.position])
    given = start is not None
    start = start if start is not None else last_pose(grid, memory)
    gp = GoalPlan(PlanResult(ok=False, requested=target), None, start, target, frame_id, map_id)
    if start is None:
        gp.plan.reason = "no start: give one (the map has no trajectory and the memory no pose)"
        gp.problem = START
        return gp
    radius = grid.config.robot_radius if robot_radius is None else float(robot_radius)
    gp.plan = plan_path(grid, start, target, radius, snap_radius=snap_radius)
    if not gp.plan.ok:
        gp.problem, gp.plan.reason = _blame(grid, start, target, radius, snap_radius, gp.plan.reason)
        if given or gp.problem != START or not _start_nearby(grid, gp, radius, snap_radius):
            return gp
    assert gp.plan.goal is not None
    gx, gy = gp.plan.goal
    moved = math.dist((gx, gy), target)
    if gp.plan.snapped:
        gp.notes.append(f"goal moved {moved:.2f} m to a reachable cell")
    gp.heading = _heading(answer, memory, grid, gp, moved)
    gp.goal = (gx, gy, gp.heading.yaw)
    return gp


def _start_nearby(grid: OccupancyGrid, gp: GoalPlan, radius: float, snap: float) -> bool:
    """The robot's last pose is cut off from the goal (a start the caller chose is never
    moved): plan from the nearest cell of the free region that reaches the goal instead, and
    say so in the notes. True when that plan succeeded (then `gp` holds it)."""
    assert gp.start is not None and gp.target is not None
    alt = start_near(grid, gp.start, gp.target, radius, snap)
    if alt is None:
        return False
    plan = plan_path(grid, alt, gp.target, radius, snap_radius=snap)
    if not plan.ok:
        return False
    (x, y), why = gp.start, gp.plan.reason.split("; give another start")[0]
    gp.notes.append(
        f"started {math.dist(gp.start, alt):.2f} m from the robot's last pose ({x:.2f}, {y:.2f}), at the "
        f"nearest cell that reaches the goal: {why}"
    )
    gp.plan, gp.start, gp.problem = plan, alt, None
    return True


def _refusal(answer: AnswerLike, map_id: str, allow_unsupported: bool) -> tuple[str, str] | None:
    """(problem, reason) when the answer must not be driven to, else None."""
    refused = refusal_of(answer, allow_unsupported, then="the robot stays put")
    if refused is not None:  # the one rule (`ravenmem.refusal`), with what it means for a robot
        return ANSWER, refused
    if not answer.found or not answer.position:
        return ANSWER, "the answer has no position to go to" + ("" if answer.found else " (not found)")
    pos = answer.position
    if len(pos) < 2 or not all(isinstance(v, (int, float)) and math.isfinite(float(v)) for v in pos):
        return ANSWER, f"bad answer position {pos!r}"
    other = getattr(answer, "map_id", None)
    if other and other != map_id:
        return MAP, (
            f"the answer is in map {other!r} but this memory's map is {map_id!r}, and no transform "
            "between them is known: align them first (ravenmem align --from A --to B --apply)"
        )
    return None


def _blame(
    grid: OccupancyGrid,
    start: tuple[float, float],
    goal: tuple[float, float],
    radius: float,
    snap: float,
    reason: str,
) -> tuple[str, str]:
    """Whether the start or the goal is why no path was found, with the reason to log. A goal
    reachable from some free region, but not from the start's, blames the start when the
    start's region is the smaller one (a start closed off by one-way ledges, say)."""
    if reason.startswith("start"):
        return START, reason + "; give another start"
    trav = grid.traversable(radius)
    labels, _ = ndimage.label(trav)
    s = grid.world_to_cell(*start)
    if not grid.contains(s) or labels[s] == 0:
        return START, f"start ({start[0]:.2f}, {start[1]:.2f}) is not in known free space; give another start"
    g = grid.world_to_cell(*goal)
    k = int(math.ceil(snap / grid.resolution))
    h, w = trav.shape
    r0, r1, c0, c1 = max(0, g[0] - k), min(h, g[0] + k + 1), max(0, g[1] - k), min(w, g[1] + k + 1)
    near = set(np.unique(labels[r0:r1, c0:c1]).tolist()) - {0} if r0 < r1 and c0 < c1 else set()
    if not near:
        return GOAL, reason
    area = grid.resolution**2
    own = float((labels == labels[s]).sum()) * area
    best = max(near, key=lambda lab: int((labels == lab).sum()))
    other = float((labels == best).sum()) * area
    if own < other:
        return START, (
            f"start ({start[0]:.2f}, {start[1]:.2f}) is cut off from the goal: its free region "
            f"({own:.1f} m^2, closed by walls or one-way ledges) does not reach the goal's "
            f"({other:.1f} m^2); give another start"
        )
    return GOAL, (
        f"goal ({goal[0]:.2f}, {goal[1]:.2f}) is unreachable: it lies in a free region "
        f"({other:.1f} m^2) the start's ({own:.1f} m^2) does not reach"
    )


def _heading(answer: AnswerLike, memory: Memory, grid: OccupancyGrid, gp: GoalPlan, moved: float) -> Heading:
    """The goal's yaw and why (see the module docstring, step 3)."""
    assert gp.plan.goal is not None and gp.target is not None
    from_model = answer.yaw is not None and answer.yaw_source == "model"
    if from_model and grid.frame.is_world_xy:
        return Heading(float(answer.yaw), "model", "the model's yaw (REP 103, about the map's z)")  # type: ignore[arg-type]
    if from_model:
        gp.notes.append("the model's yaw is about world z, which is not this map's up: it is not used")
    if gp.plan.snapped and moved > grid.resolution:
        (gx, gy), (tx, ty) = gp.plan.goal, gp.target
        return Heading(
            math.atan2(ty - gy, tx - gx),
            "target",
            f"facing the answer's position from the goal ({moved:.2f} m away)",
        )
    pose = _evidence_pose(memory, answer, grid)
    if pose is not None:
        return Heading(heading_of(grid, pose), "evidence", "the way the evidence camera looked from the goal")
    if len(gp.plan.waypoints) >= 2:
        (ax, ay), (bx, by) = gp.plan.waypoints[-2], gp.plan.waypoints[-1]
        if math.hypot(bx - ax, by - ay) > 1e-9:
            return Heading(math.atan2(by - ay, bx - ax), "path", "the direction of the path's last leg")
    gp.notes.append("no heading to go by: the goal faces map +x")
    return Heading(0.0, "default", "nothing gave a heading: map +x")


def _evidence_pose(mem: Memory, answer: AnswerLike, grid: OccupancyGrid) -> Pose | None:
    """The pose of the answer's first evidence memory: the stored record's full pose when it is
    this memory's (same id, time and place: an answer from another memory of the same map names
    ids of its own), else the pose the evidence carries, on z-up maps (its yaw is a heading)."""
    if not answer.evidence:
        return None
    ev = answer.evidence[0]
    ev_id = getattr(ev, "id", None)
    try:
        x, y, z = (float(getattr(ev, k)) for k in ("x", "y", "z"))
        yaw, t = float(getattr(ev, "yaw", 0.0)), float(ev.t)
    except (AttributeError, TypeError, ValueError):
        return None
    xyz = (x, y, z)
    try:
        (rec,) = mem.get([int(ev_id)])  # type: ignore[arg-type]
    except (ValueError, TypeError):  # not an id, or no such memory (NotFoundError is a ValueError)
        rec = None
    if rec is not None and abs(rec.t - t) < 1e-6 and math.dist(rec.pose.xyz, xyz) < 1e-6:
        return rec.pose
    return Pose(x, y, z, yaw) if grid.frame.is_world_xy else None
