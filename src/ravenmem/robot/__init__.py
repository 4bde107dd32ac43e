"""The robot: exploration and missions, the loop that uses the simulator (`ravenmem.sim`) and
navigation (`ravenmem.nav`) together. It sits above both; neither imports it."""

from .explore import ExploreConfig, Explorer, ExploreReport, map_config
from .mission import NavOutcome, explore_into, load_exploration, navigate_to

__all__ = [
    "ExploreConfig",
    "ExploreReport",
    "Explorer",
    "NavOutcome",
    "explore_into",
    "load_exploration",
    "map_config",
    "navigate_to",
]
