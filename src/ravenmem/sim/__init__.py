"""Simulated robots: environments (ViZDoom), a waypoint controller, demo queries and scoring."""

from .base import ENVIRONMENTS, Environment, Observation, RobotSpec, SceneObject, create_env

__all__ = ["ENVIRONMENTS", "Environment", "Observation", "RobotSpec", "SceneObject", "create_env"]
