"""Navigation: occupancy maps from depth, A* planning with goal snapping, frontier exploration."""

from .astar import astar, distance_field, simplify
from .base import PLANNERS, Intrinsics, Planner, PlanResult, create_planner
from .frontier import Frontier, find_frontiers, frontier_mask
from .grid import MapConfig, OccupancyGrid
from .planning import plan_path, snap_goal

__all__ = [
    "PLANNERS",
    "Frontier",
    "Intrinsics",
    "MapConfig",
    "OccupancyGrid",
    "PlanResult",
    "Planner",
    "astar",
    "create_planner",
    "distance_field",
    "find_frontiers",
    "frontier_mask",
    "plan_path",
    "simplify",
    "snap_goal",
]
