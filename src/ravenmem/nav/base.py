"""The navigation axis: plan results and the planner protocol.

Planners work on a boolean traversability grid (True = the robot's centre may stand there,
i.e. free space already inflated by the robot radius) in cell coordinates (row, col), so that
any planner (A*, a library, a learned one) can be swapped in by name without knowing how the
map was built. World <-> cell conversion lives in `OccupancyGrid`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from ..registry import Registry

Cell = tuple[int, int]


@dataclass
class PlanResult:
    """What a planner found. `ok` False carries a one-line `reason` a user can act on.

    `cells` is the full 8-connected cell path; `waypoints` the simplified world-frame path
    (metres) the controller drives; `goal` is the goal actually used, which differs from
    `requested` when the requested goal had to be snapped to a reachable free cell.
    """

    ok: bool
    reason: str = ""
    cells: list[Cell] = field(default_factory=list)
    waypoints: list[tuple[float, float]] = field(default_factory=list)
    length_m: float = math.inf
    requested: tuple[float, float] | None = None
    goal: tuple[float, float] | None = None
    snapped: bool = False
    expanded: int = 0


@runtime_checkable
class Planner(Protocol):
    """Shortest 8-connected path on a traversability grid, in cells."""

    name: str

    def plan(self, traversable: np.ndarray, start: Cell, goal: Cell) -> tuple[list[Cell] | None, float, int]:
        """Return (cells or None when unreachable, cost in cells, nodes expanded)."""
        ...


PLANNERS: Registry[Planner] = Registry("planner", "ravenmem.planners", {"astar": "ravenmem.nav.astar"})


def create_planner(spec: str = "astar") -> Planner:
    """Create a planner by name (`astar` is built in)."""
    return PLANNERS.create(spec)
