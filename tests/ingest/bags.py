"""Write small ROS 1 / ROS 2 (sqlite3, MCAP) bags with rosbags' own writers, for the tests.

Scenario (header times; bag receive time = header + BAG_DELAY):
- /camera/image_raw (Image): frames at 10.0 + 0.1 i, i = 0..5, encodings ENCODINGS, colour RGB;
  then a yuv422 frame at 10.6 (unsupported), an rgb8 frame at 10.9 (after the poses end) and an
  rgb8 frame with a zero stamp received at 10.45 + BAG_DELAY = 10.65 (falls back to bag time).
- /camera/compressed (CompressedImage): jpeg at 10.05, png at 10.15, garbage at 10.25.
- /odom (Odometry), /pose (PoseStamped), /amcl_pose (PoseWithCovarianceStamped): x = t - 10, yaw = 0.5 (t - 10), t = 9.95 .. 10.75.
- /tf: odom -> base_link with the same motion; /tf_static: map -> odom, (1, 0, 0) and yaw 90 deg.
"""

from __future__ import annotations

import io
import math
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image
from rosbags.rosbag1 import Writer as Writer1
from rosbags.rosbag2 import StoragePlugin
from rosbags.rosbag2 import Writer as Writer2
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

RGB = (200, 100, 50)
ENCODINGS = ["rgb8", "bgr8", "mono8", "rgba8", "bgra8", "mono16"]
BAG_DELAY = 0.2
H, W = 4, 6
POSE_TIMES = [9.95 + 0.1 * k for k in range(9)]  # 9.95 .. 10.75


def _typestore(ros1: bool) -> Any:
    ts = get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)
    if "tf2_msgs/msg/TFMessage" not in ts.types:
        ts.register(
            get_types_from_msg("geometry_msgs/TransformStamped[] transforms", "tf2_msgs/msg/TFMessage")
        )
    return ts


class _Msgs:
    def __init__(self, ts: Any, ros1: bool) -> None:
        self.ts, self.ros1 = ts, ros1

    def T(self, name: str) -> Any:
        return self.ts.types[name]

    def header(self, t: float, frame: str) -> Any:
        sec = int(math.floor(t))
        stamp = self.T("builtin_interfaces/msg/Time")(
            sec=sec, nanosec=int(round((t - sec) * 1e9)) if t else 0
        )
        if self.ros1:
            return self.T("std_msgs/msg/Header")(seq=0, stamp=stamp, frame_id=frame)
        return self.T("std_msgs/msg/Header")(stamp=stamp, frame_id=frame)

    def pose(self, x: float, y: float, yaw: float) -> Any:
        p = self.T("geometry_msgs/msg/Point")(x=x, y=y, z=0.0)
        q = self.T("geometry_msgs/msg/Quaternion")(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))
        return self.T("geometry_msgs/msg/Pose")(position=p, orientation=q)

    def image(self, t: float, enc: str) -> Any:
        rgb = np.array(RGB, np.uint8)
        pix = {
            "rgb8": rgb,
            "bgr8": rgb[::-1],
            "rgba8": np.r_[rgb, 255],
            "bgra8": np.r_[rgb[::-1], 255],
            "mono8": np.array([120], np.uint8),
            "yuv422": np.array([1, 2], np.uint8),
        }
        if enc == "mono16":
            row = np.tile(np.array([1000, 4000], "<u2"), W // 2).view(np.uint8)
            step, data = W * 2, np.tile(row, H)
        else:
            px = pix[enc]
            step = W * len(px) + 3  # padded rows: the decoder must honour `step`
            data = np.tile(np.r_[np.tile(px, W), np.zeros(3, np.uint8)], H).astype(np.uint8)
        return self.T("sensor_msgs/msg/Image")(
            header=self.header(t, "cam"),
            height=H,
            width=W,
            encoding=enc,
            is_bigendian=0,
            step=step,
            data=data,
        )

    def compressed(self, t: float, fmt: str) -> Any:
        buf = io.BytesIO()
        if fmt == "garbage":
            buf.write(b"definitely not an image")
        else:
            Image.fromarray(np.full((H * 4, W * 4, 3), RGB, np.uint8)).save(buf, format=fmt.upper())
        data = np.frombuffer(buf.getvalue(), np.uint8)
        return self.T("sensor_msgs/msg/CompressedImage")(header=self.header(t, "cam"), format=fmt, data=data)

    def odom(self, t: float) -> Any:
        cov = self.T("geometry_msgs/msg/PoseWithCovariance")(
            pose=self.pose(t - 10, 0, 0.5 * (t - 10)), covariance=np.zeros(36)
        )
        v = self.T("geometry_msgs/msg/Vector3")(x=0.0, y=0.0, z=0.0)
        tw = self.T("geometry_msgs/msg/TwistWithCovariance")(
            twist=self.T("geometry_msgs/msg/Twist")(linear=v, angular=v), covariance=np.zeros(36)
        )
        return self.T("nav_msgs/msg/Odometry")(
            header=self.header(t, "odom"), child_frame_id="base_link", pose=cov, twist=tw
        )

    def pose_stamped(self, t: float) -> Any:
        return self.T("geometry_msgs/msg/PoseStamped")(
            header=self.header(t, "map"), pose=self.pose(t - 10, 0, 0.5 * (t - 10))
        )

    def pose_cov(self, t: float) -> Any:
        cov = self.T("geometry_msgs/msg/PoseWithCovariance")(
            pose=self.pose(t - 10, 0, 0.5 * (t - 10)), covariance=np.zeros(36)
        )
        return self.T("geometry_msgs/msg/PoseWithCovarianceStamped")(header=self.header(t, "map"), pose=cov)

    def tf(self, t: float, parent: str, child: str, x: float, y: float, yaw: float) -> Any:
        tr = self.T("geometry_msgs/msg/Vector3")(x=x, y=y, z=0.0)
        q = self.T("geometry_msgs/msg/Quaternion")(x=0.0, y=0.0, z=math.sin(yaw / 2), w=math.cos(yaw / 2))
        ts = self.T("geometry_msgs/msg/TransformStamped")(
            header=self.header(t, parent),
            child_frame_id=child,
            transform=self.T("geometry_msgs/msg/Transform")(translation=tr, rotation=q),
        )
        return self.T("tf2_msgs/msg/TFMessage")(transforms=[ts])


def scenario(m: _Msgs, slash: str) -> list[tuple[str, float, Any]]:
    """(topic, bag time, message) in bag-time order."""
    out: list[tuple[str, float, Any]] = []
    for i, enc in enumerate(ENCODINGS):
        out.append(("/camera/image_raw", 10.0 + 0.1 * i, m.image(10.0 + 0.1 * i, enc)))
    out.append(("/camera/image_raw", 10.6, m.image(10.6, "yuv422")))
    out.append(("/camera/image_raw", 10.9, m.image(10.9, "rgb8")))
    out.append(("/camera/image_raw", 10.45, m.image(0.0, "rgb8")))
    for t, fmt in ((10.05, "jpeg"), (10.15, "png"), (10.25, "garbage")):
        out.append(("/camera/compressed", t, m.compressed(t, fmt)))
    for t in POSE_TIMES:
        out.append(("/odom", t, m.odom(t)))
        out.append(("/pose", t, m.pose_stamped(t)))
        out.append(("/amcl_pose", t, m.pose_cov(t)))
        out.append(("/tf", t, m.tf(t, f"{slash}odom", f"{slash}base_link", t - 10, 0.0, 0.5 * (t - 10))))
    out.append(("/tf_static", 9.0, m.tf(9.0, f"{slash}map", f"{slash}odom", 1.0, 0.0, math.pi / 2)))
    return sorted(out, key=lambda x: x[1])


def write_bag(path: Path, kind: str, only: set[str] | None = None) -> Path:
    """kind: ros1 (path.bag), sqlite3 or mcap (ROS 2 bag folder); `only` keeps those topics."""
    ros1 = kind == "ros1"
    ts = _typestore(ros1)
    m = _Msgs(ts, ros1)
    msgs = [x for x in scenario(m, "/" if ros1 else "") if only is None or x[0] in only]
    writer: Any
    if ros1:
        writer = Writer1(path)
    else:
        plugin = StoragePlugin.MCAP if kind == "mcap" else StoragePlugin.SQLITE3
        writer = Writer2(path, version=9, storage_plugin=plugin)
    with writer:
        conns: dict[str, Any] = {}
        for topic, _, msg in msgs:
            if topic not in conns:
                conns[topic] = writer.add_connection(topic, msg.__msgtype__, typestore=ts)
        for topic, t, msg in msgs:
            data = ts.serialize_ros1(msg, msg.__msgtype__) if ros1 else ts.serialize_cdr(msg, msg.__msgtype__)
            writer.write(conns[topic], int(round((t + BAG_DELAY) * 1e9)), data)
    return path
