"""The node's settings, every one a declared ROS parameter (`-p name:=value`, `--params-file`).

Defaults follow REP 105 (`map` -> `odom` -> `base_link`) and the usual topic names. Topic names
are relative, so `-r __ns:=/bot1` moves them under the namespace; the services are the node's
own (`~/ask`: `/ravenmem/ask` for the node `ravenmem`); `/tf`, `/tf_static` and `/diagnostics`
are absolute, as ROS tools expect them.
"""

from __future__ import annotations

from dataclasses import dataclass, field, fields
from typing import Any

from ..errors import InputError

TRANSPORTS = ("auto", "raw", "compressed")
QOS = ("sensor_data", "reliable", "best_effort")


@dataclass(frozen=True)
class NodeSettings:
    """What `ravenmem ros run` subscribes to and how (see each field's ROS parameter)."""

    image_topic: str = "camera/image_raw"
    # more cameras, each its own keyframe stream (source `<source>:<topic>`), posed by the same
    # odometry or TF; the same transport rule as image_topic
    image_topics: tuple[str, ...] = field(default=())
    image_transport: str = "auto"  # raw (Image), compressed (CompressedImage on <topic>/compressed), auto
    camera_info_topic: str = "camera/camera_info"
    odom_topic: str = "odom"  # nav_msgs/Odometry; empty: poses from /tf
    map_frame: str = "map"
    odom_frame: str = "odom"
    base_frame: str = "base_link"
    map_topic: str = "map"  # nav_msgs/OccupancyGrid (transient local); empty: none
    goal_topic: str = "goal_pose"  # geometry_msgs/PoseStamped; empty: none
    navigate_action: str = ""  # nav2_msgs/action/NavigateToPose name (e.g. navigate_to_pose); empty: none
    keyframes: str = ""  # keyframe rules as for ingest (empty: the defaults; `all`)
    method: str = ""  # how questions are answered (empty: raven with a model, else offline)
    model: str = ""  # the VLM (with base_url); empty: RAVENMEM_VLM_MODEL or none
    base_url: str = ""
    source: str = "ros"  # the memories' source name
    image_qos: str = "sensor_data"
    image_depth: int = 60  # images the subscription holds until the node takes them (2 s at 30 Hz)
    pose_qos: str = "best_effort"  # a best-effort subscription matches reliable and best-effort publishers
    queue_size: int = 32  # images waiting for their pose at once
    writer_depth: int = 16  # frames handed to the writer and not yet stored; past it a frame is skipped
    pose_wait: float = 1.0  # seconds an image waits for the poses that bracket it
    history: float = 30.0  # seconds of poses kept
    max_gap: float = 0.5  # longest gap between two poses an image may be interpolated in
    diagnostics_period: float = 1.0
    markers_period: float = 5.0  # seconds between MarkerArrays of the memories; 0: none

    @classmethod
    def declare(cls, node: Any) -> NodeSettings:
        """Declare every field as a ROS parameter (its default here) and read them back."""
        cls.declare_all(node)
        return cls.read(node)

    @classmethod
    def declare_all(cls, node: Any) -> None:
        """Declare every field not declared yet (a managed node declares them when it is made,
        so `ros2 param set` works before `configure`, and reads them at each `configure`)."""
        from rcl_interfaces.msg import ParameterDescriptor
        from rclpy.parameter import Parameter

        for f in fields(cls):
            if node.has_parameter(f.name):
                continue
            if f.name == "image_topics":  # a string array (an empty default has no type)
                node.declare_parameter(f.name, Parameter.Type.STRING_ARRAY)
            else:  # dynamic typing: `-p pose_wait:=2` (an integer) is as good as 2.0
                node.declare_parameter(f.name, f.default, ParameterDescriptor(dynamic_typing=True))

    @classmethod
    def read(cls, node: Any) -> NodeSettings:
        """The declared parameters' values, checked (a one-line `InputError` naming the first
        one the node cannot use)."""
        from rclpy.exceptions import ParameterUninitializedException

        values: dict[str, Any] = {}
        for f in fields(cls):
            if f.name == "image_topics":
                try:
                    values[f.name] = tuple(str(t) for t in node.get_parameter(f.name).value or ())
                except ParameterUninitializedException:
                    values[f.name] = ()
                continue
            v = node.get_parameter(f.name).value
            kind: type = type(f.default)
            try:
                values[f.name] = kind("" if v is None else v) if kind is str else kind(v)
            except (TypeError, ValueError):
                raise InputError(f"{f.name}: expected {kind.__name__}, got {v!r}") from None
        return cls(**values).checked()

    @property
    def cameras(self) -> tuple[str, ...]:
        return (self.image_topic, *self.image_topics)

    def source_of(self, topic: str) -> str:
        """The memories' source name of a camera: `source` for the first, `source:topic` else
        (the writer keeps keyframe state per source, so cameras do not thin each other out)."""
        return self.source if topic == self.image_topic else f"{self.source}:{topic.strip('/')}"

    def checked(self) -> NodeSettings:
        """A one-line `InputError` naming the parameter for a value the node cannot use."""
        if self.image_transport not in TRANSPORTS:
            raise InputError(f"image_transport: one of {', '.join(TRANSPORTS)}, got {self.image_transport!r}")
        for name in ("image_qos", "pose_qos"):
            if getattr(self, name) not in QOS:
                raise InputError(f"{name}: one of {', '.join(QOS)}, got {getattr(self, name)!r}")
        if not self.image_topic.strip() or not all(t.strip() for t in self.image_topics):
            raise InputError("image_topic, image_topics: a topic name must not be empty")
        if len(self.cameras) != len(set(self.cameras)):
            raise InputError("image_topics: a camera topic is given twice")
        if not self.odom_topic and not self.base_frame:
            raise InputError("base_frame: must not be empty when poses come from /tf")
        if not 1 <= self.image_depth <= 1000:
            raise InputError(f"image_depth: from 1 to 1000, got {self.image_depth}")
        if not 1 <= self.writer_depth <= 256:
            raise InputError(f"writer_depth: from 1 to 256, got {self.writer_depth}")
        if not 1 <= self.queue_size <= 10_000:
            raise InputError(f"queue_size: from 1 to 10000, got {self.queue_size}")
        for name in ("pose_wait", "history", "max_gap", "diagnostics_period", "markers_period"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and 0 <= v <= 86_400):
                raise InputError(f"{name}: seconds from 0 to 86400, got {v!r}")
        if self.diagnostics_period <= 0:
            raise InputError("diagnostics_period: must be > 0")
        if bool(self.model) != bool(self.base_url):
            raise InputError("model and base_url: give both, or neither")
        return self
