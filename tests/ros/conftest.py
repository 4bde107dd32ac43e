"""The agent tests' fixtures (the scene memory, the colour embedder as a plugin of the real
command), for the ROS tests that ask questions through every front end."""

from tests.agent.conftest import color_plugin, mem_path  # noqa: F401
