"""The records' own rules: the heading of a quaternion, read the same everywhere."""

from __future__ import annotations

import math

import pytest

from ravenmem.nav.goals import read_pose_stamped
from ravenmem.types import Pose, yaw_of


@pytest.mark.parametrize("yaw", [0.0, 0.3, -1.2, math.pi / 2, 3.0])
def test_the_heading_of_a_quaternion_is_one_formula(yaw: float) -> None:
    q = (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))
    assert yaw_of(*q) == pytest.approx(yaw)
    assert Pose.from_quaternion(1.0, 2.0, 0.0, *q).yaw == pytest.approx(yaw)
    msg = {
        "header": {"frame_id": "map"},
        "pose": {"position": {"x": 1.0, "y": 2.0}, "orientation": dict(zip("xyzw", q))},
    }
    x, y, got, frame = read_pose_stamped(msg)
    assert (x, y, frame) == (1.0, 2.0, "map") and got == pytest.approx(yaw)


def test_a_rolled_camera_keeps_its_heading() -> None:
    roll = 0.4  # about x: the heading does not change
    q = (math.sin(roll / 2), 0.0, 0.0, math.cos(roll / 2))
    assert yaw_of(*q) == pytest.approx(0.0, abs=1e-12)
