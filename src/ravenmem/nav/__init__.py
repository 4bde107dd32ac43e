"""Navigation: occupancy maps from depth, A* planning with goal snapping, frontier exploration."""

from .astar import astar, distance_field, simplify
from .base import PLANNERS, Planner, PlanResult, create_planner
from .frame import MapFrame
from .frontier import Frontier, find_frontiers, frontier_mask
from .grid import MapConfig, OccupancyGrid, load_map
from .planning import plan_path, snap_goal

__all__ = [
    "PLANNERS",
    "Frontier",
    "MapConfig",
    "MapFrame",
    "OccupancyGrid",
    "PlanResult",
    "Planner",
    "astar",
    "create_planner",
    "distance_field",
    "find_frontiers",
    "load_map",
    "frontier_mask",
    "plan_path",
    "simplify",
    "snap_goal",
]
