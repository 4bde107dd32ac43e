"""Real ROS 2 messages as CDR bytes (what zenoh-bridge-ros2dds and rmw_zenoh carry), made with
rosbags, for the robot link's tests. Messages come from the bag tests' builders (tests/ingest/bags.py)."""

from __future__ import annotations

import io
import math
from typing import Any

import numpy as np
from PIL import Image

from ravenmem.ros import msgs as rosmsg
from tests.ingest.bags import _Msgs

MSGS = _Msgs(rosmsg.typestore(), ros1=False)


def cdr(msg: Any) -> bytes:
    return rosmsg.serialize(msg, msg.__msgtype__)


def picture(i: int, h: int = 24, w: int = 32) -> np.ndarray:
    """A distinct RGB picture per i: a colour ramp with a bright square at a position set by i."""
    img = np.zeros((h, w, 3), np.uint8)
    img[:, :, 0] = np.linspace(0, 255, w, dtype=np.uint8)[None, :]
    img[:, :, 1] = (40 * i) % 256
    img[:, :, 2] = np.linspace(255, 0, h, dtype=np.uint8)[:, None]
    img[4:10, 2 + 3 * i : 8 + 3 * i] = 255
    return img


def image(t: float, rgb: np.ndarray, encoding: str = "rgb8", frame: str = "camera") -> bytes:
    """sensor_msgs/Image with padded rows (the decoder must honour `step`)."""
    h, w, _ = rgb.shape
    px = rgb if encoding == "rgb8" else rgb[:, :, ::-1]
    step = w * 3 + 4
    data = np.zeros((h, step), np.uint8)
    data[:, : w * 3] = px.reshape(h, w * 3)
    msg = MSGS.T("sensor_msgs/msg/Image")(
        header=MSGS.header(t, frame),
        height=h,
        width=w,
        encoding=encoding,
        is_bigendian=0,
        step=step,
        data=data.reshape(-1),
    )
    return cdr(msg)


def jpeg(t: float, rgb: np.ndarray, fmt: str = "jpeg") -> bytes:
    buf = io.BytesIO()
    Image.fromarray(rgb).save(buf, format=fmt.upper(), quality=95)
    msg = MSGS.T("sensor_msgs/msg/CompressedImage")(
        header=MSGS.header(t, "camera"), format=fmt, data=np.frombuffer(buf.getvalue(), np.uint8)
    )
    return cdr(msg)


def motion(t: float) -> tuple[float, float, float]:
    """The robot's motion in the tests: x = t - 10 m, y = 0.5 m, yaw = 0.5 (t - 10) rad."""
    return t - 10.0, 0.5, 0.5 * (t - 10.0)


def odom(t: float) -> bytes:
    x, y, yaw = motion(t)
    cov = MSGS.T("geometry_msgs/msg/PoseWithCovariance")(pose=MSGS.pose(x, y, yaw), covariance=np.zeros(36))
    v = MSGS.T("geometry_msgs/msg/Vector3")(x=0.0, y=0.0, z=0.0)
    tw = MSGS.T("geometry_msgs/msg/TwistWithCovariance")(
        twist=MSGS.T("geometry_msgs/msg/Twist")(linear=v, angular=v), covariance=np.zeros(36)
    )
    msg = MSGS.T("nav_msgs/msg/Odometry")(
        header=MSGS.header(t, "odom"), child_frame_id="base_link", pose=cov, twist=tw
    )
    return cdr(msg)


def pose_stamped(t: float) -> bytes:
    x, y, yaw = motion(t)
    return cdr(
        MSGS.T("geometry_msgs/msg/PoseStamped")(header=MSGS.header(t, "map"), pose=MSGS.pose(x, y, yaw))
    )


def tf(t: float) -> bytes:
    """/tf: odom -> base_link moving with `motion` (the map -> odom part comes on /tf_static)."""
    x, y, yaw = motion(t)
    return cdr(MSGS.tf(t, "odom", "base_link", x, y, yaw))


def tf_static() -> bytes:
    """/tf_static: map -> odom, (1, 0, 0) and yaw 90 degrees."""
    return cdr(MSGS.tf(1.0, "map", "odom", 1.0, 0.0, math.pi / 2))


def in_map(t: float) -> tuple[float, float, float]:
    """`motion` seen from map through the static map -> odom transform of `tf_static`."""
    x, y, yaw = motion(t)
    return 1.0 - y, x, yaw + math.pi / 2
