"""The simulator axis: an environment a robot can look around in and drive through.

An environment gives observations (RGB, metric depth, pose, time, and which ground-truth
objects are in view) and takes low-level commands (`step(forward, turn)`); waypoint following
is a controller on top (`ravenmem.sim.control`), the same for every backend. Backends also
publish the scene's ground-truth objects, used only to generate queries and score answers,
never by the robot's memory or planner.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from ..registry import Registry
from ..types import Intrinsics, Pose


@dataclass
class Observation:
    """What the robot senses at one instant. `depth` is metres along the optical axis (0 = no
    reading), same size as `rgb`; `pose.z` is the camera's height; `t` is epoch seconds (the
    episode's start plus simulated time); `visible` holds ids of ground-truth objects in view
    (empty where unknown) and `visible_boxes` where they are in the picture (x, y, width,
    height in pixels, where the backend knows it): ground truth for scoring and oracle
    perception only, never seen by the memory or the planner."""

    rgb: np.ndarray
    depth: np.ndarray
    pose: Pose
    t: float
    step: int = 0
    visible: tuple[int, ...] = ()
    floor_z: float | None = None  # height of the floor under the robot (m), when known
    visible_boxes: dict[int, tuple[int, int, int, int]] = field(default_factory=dict)

    @property
    def visible_px(self) -> dict[int, int]:
        """Size in the picture (box pixels) of each visible object, where known."""
        return {k: w * h for k, (_, _, w, h) in self.visible_boxes.items()}

    @property
    def camera_height(self) -> float | None:
        """The camera's height above the robot's floor right now (it dips on stairs in Doom)."""
        return None if self.floor_z is None else self.pose.z - self.floor_z


@dataclass(frozen=True)
class SceneObject:
    """A ground-truth object: backend id, class name (e.g. 'GreenArmor') and position (m)."""

    id: int
    kind: str
    x: float
    y: float
    z: float = 0.0


@dataclass(frozen=True)
class RobotSpec:
    """Body of the simulated robot, in metres (and metres per second)."""

    radius: float
    height: float
    step_height: float
    camera_height: float
    max_speed: float


@runtime_checkable
class Environment(Protocol):
    name: str
    intrinsics: Intrinsics
    robot: RobotSpec

    def reset(self) -> Observation:
        """Start a new episode at the map's start position."""
        ...

    def observe(self) -> Observation: ...

    def step(self, forward: float, turn: float) -> Observation:
        """One control tick: `forward` in [-1, 1] (fraction of max speed), `turn` radians
        (positive = left, counter-clockwise seen from above)."""
        ...

    def objects(self) -> list[SceneObject]:
        """Ground-truth objects for queries and scoring."""
        ...

    def close(self) -> None: ...


ENVIRONMENTS: Registry[Environment] = Registry(
    "environment",
    "ravenmem.environments",
    {"vizdoom": "ravenmem.sim.vizdoom", "synthetic": "ravenmem.sim.worlds"},
)


def create_env(spec: str = "vizdoom:freedoom2/MAP01", **kwargs: object) -> Environment:
    """Create an environment by spec, e.g. `vizdoom:freedoom2/MAP01` or `synthetic:rooms`."""
    return ENVIRONMENTS.create(spec, **kwargs)
