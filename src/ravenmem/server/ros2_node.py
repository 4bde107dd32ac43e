"""A ROS 2 node (rclpy) for robots that run ROS 2 natively: the robot link without Zenoh.

NOT RUN HERE: rclpy comes with a ROS 2 installation (it is not on PyPI), and the machine this
was built on has none. What is tested is everything it calls: this module only adapts rclpy
callbacks to the link's logic (`zenoh_link.RosLink`), which the tests run with real CDR bytes.
The subscriptions are made with `raw=True`, so rclpy hands over each message's CDR bytes, the
very bytes the Zenoh link receives; the goal is published as the CDR bytes `RosLink.goal_bytes`
makes (rclpy publishers take serialized bytes). No message is converted here.

    source /opt/ros/jazzy/setup.bash
    python -m ravenmem.server.ros2_node --memory robot.mem \\
        --link image=/camera/color/image_raw,pose=/odom,goal=/goal_pose --keyframes fps=1
"""

from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path
from typing import Any

from ..errors import MissingDependencyError, RavenmemError
from ..ingest import rosmsg
from .zenoh_link import LinkConfig, RosLink, Sink, parse_link_spec, writer_sink

TICK_S = 0.1  # how often waiting images are settled


def _ros() -> tuple[Any, Any, Any]:
    """rclpy, rclpy.qos and rosidl's message lookup, or a clear error."""
    try:
        rclpy = importlib.import_module("rclpy")
        qos = importlib.import_module("rclpy.qos")
        utils = importlib.import_module("rosidl_runtime_py.utilities")
    except ImportError as e:
        raise MissingDependencyError(
            f"rclpy is not importable ({e}): it comes with ROS 2; source /opt/ros/<distro>/setup.bash first"
        ) from e
    return rclpy, qos, utils


def topic(key: str) -> str:
    """The ROS topic of a link key (`camera/color/image_raw` -> `/camera/color/image_raw`)."""
    return "/" + key.strip("/")


class LinkNode:
    """Subscribes to the link's topics with raw (CDR) callbacks that feed one RosLink.

    rclpy's default executor runs callbacks one at a time, so the RosLink has one caller, as
    in the Zenoh link. `publish_goal(answer)` publishes an answer's position on the goal topic.
    """

    def __init__(self, cfg: LinkConfig, sink: Sink, name: str = "ravenmem") -> None:
        rclpy, qos, utils = _ros()
        from rclpy.node import Node

        self.cfg = cfg
        self.link = RosLink(cfg, sink)
        self.node: Any = Node(name)
        types = dict(self.node.get_topic_names_and_types())

        def msg_class(key: str, given: str | None, default: str) -> Any:
            found = types.get(topic(key), [])
            return utils.get_message(given or (found[0] if found else default))

        img_cls = msg_class(cfg.image, cfg.image_type, rosmsg.IMAGE)
        pose_cls = msg_class(cfg.pose, cfg.pose_type, rosmsg.TF if cfg.tf else rosmsg.ODOMETRY)
        sensor = qos.qos_profile_sensor_data
        self.node.create_subscription(img_cls, topic(cfg.image), self._on(cfg.image, True), sensor, raw=True)
        self.node.create_subscription(pose_cls, topic(cfg.pose), self._on(cfg.pose, False), 100, raw=True)
        if cfg.tf_static_key:
            latched = qos.QoSProfile(depth=100, durability=qos.DurabilityPolicy.TRANSIENT_LOCAL)
            static_cb = self._on(cfg.tf_static_key, False)
            tf_cls = utils.get_message(rosmsg.TF)
            self.node.create_subscription(tf_cls, topic(cfg.tf_static_key), static_cb, latched, raw=True)
        self.goal_pub = None
        if cfg.goal:
            self.goal_pub = self.node.create_publisher(
                utils.get_message(rosmsg.POSE_STAMPED), topic(cfg.goal), 10
            )
        self.node.create_timer(TICK_S, self.link.tick)

    def _on(self, key: str, image: bool) -> Any:
        def callback(raw: bytes) -> None:
            if image:
                self.link.image(key, raw)
            else:
                self.link.pose(key, raw)

        return callback

    def publish_goal(self, answer: dict[str, Any]) -> bool:
        """Publish the answer's position as a PoseStamped; False without a goal topic or position."""
        payload = self.link.goal_bytes(answer) if self.goal_pub is not None else None
        if payload is None or self.goal_pub is None:
            return False
        self.goal_pub.publish(payload)
        self.link.stats.add("goals")
        return True


def main(argv: list[str] | None = None) -> None:
    """Run the node on a memory until Ctrl-C: frames through one live writer (as the service's)."""
    ap = argparse.ArgumentParser(prog="python -m ravenmem.server.ros2_node", description=__doc__)
    ap.add_argument("--memory", required=True, help="memory folder (created when missing)")
    ap.add_argument(
        "--link", required=True, help="image=TOPIC,pose=TOPIC[,key=value...] as for serve --zenoh"
    )
    ap.add_argument("--keyframes", default=None, help="keyframe rule, e.g. fps=1,min_translation=0.2")
    args = ap.parse_args(argv)
    cfg = parse_link_spec(args.link)
    rclpy, _, _ = _ros()
    import ravenmem

    from ..ingest.keyframes import parse_keyframes
    from ..memory.folder import is_memory
    from .live import LiveWriter

    path = Path(args.memory)
    mem = ravenmem.open(path) if is_memory(path) else ravenmem.create(path)
    mem.acquire_writer()
    writer = LiveWriter(mem, parse_keyframes(args.keyframes)).start()
    rclpy.init()
    node = LinkNode(cfg, writer_sink(writer, cfg.source))
    try:
        rclpy.spin(node.node)
    except KeyboardInterrupt:
        pass
    finally:
        node.link.flush()
        node.node.destroy_node()
        rclpy.shutdown()
        writer.close()
        if writer.stats.seen:
            mem.record_ingest(writer.report())
        mem.close()


if __name__ == "__main__":
    try:
        main()
    except RavenmemError as e:  # one line, as the ravenmem command prints it
        sys.stderr.write(f"error: {e}\n")
        sys.exit(2)
