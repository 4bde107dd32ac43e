"""Shared fixtures of the robot tests."""

from __future__ import annotations

from collections.abc import Iterator

import pytest

from tests.robot.changes_world import World, build_world


@pytest.fixture(scope="session")
def world(tmp_path_factory) -> Iterator[World]:
    """The world that changes (tests/robot/changes_world.py), built once per session."""
    w = build_world(tmp_path_factory.mktemp("changes") / "rooms.mem")
    yield w
    w.mem.close()
