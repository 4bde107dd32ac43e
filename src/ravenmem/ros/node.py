"""A ROS 2 node (rclpy) for robots that run ROS 2 natively: the robot link without Zenoh.

NOT RUN HERE: rclpy comes with a ROS 2 installation (it is not on PyPI), and the machine this
was built on has none. What the node does is in `NodeLogic`, which needs no rclpy and is
tested: frames through the link's logic (`ros.link.RosLink`) with the very CDR bytes rclpy
hands over (`raw=True` subscriptions), goals as the CDR of the answers' `nav.goals` plans
(rclpy publishers take serialized bytes), and `ravenmem_msgs/srv/Ask` / `Search` answered by
`ros.services` (the same replies the Zenoh link gives). `LinkNode` only wires rclpy to it.
The services need `ravenmem_msgs` built in the workspace (`colcon build`, see docs/serve.md).

    source /opt/ros/jazzy/setup.bash && source ~/ws/install/setup.bash
    python -m ravenmem.ros.node --memory robot.mem \\
        --link image=/camera/color/image_raw,pose=/odom,goal=/goal_pose --keyframes fps=1
"""

from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..errors import MissingDependencyError, RavenmemError
from ..threads import share_cores
from . import msgs
from .link import LinkConfig, RosLink, goal_bytes, goal_of, writer_sink
from .services import ServiceBackend, ask_reply, search_reply

if TYPE_CHECKING:
    from ..agent.ask import AskResult
    from ..runtime.service import Service

TICK_S = 0.1  # how often waiting images are settled


def _ros() -> tuple[Any, Any, Any]:
    """rclpy, rclpy.qos and rosidl's type lookup, or a clear error."""
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


class NodeLogic:
    """Everything the node does, without rclpy: one `RosLink` into the service's writer, the
    goal of each answer, and the two services' replies (dict in, dict out)."""

    def __init__(self, cfg: LinkConfig, service: Service) -> None:
        self.cfg = cfg
        self.service = service
        self.link = RosLink(cfg, writer_sink(service.writer, cfg.source), frame_check=service.frame_check)  # type: ignore[arg-type]
        self.backend = ServiceBackend(service, self.link.poses.latest_xy)

    def goal(self, result: AskResult, stamp: float | None = None) -> bytes | None:
        """CDR of the goal PoseStamped to publish for a result (planned now when the question
        asked for no plan, from the robot's latest pose), None when there is none."""
        goal = goal_of(self.service.plan_of(result, self.link.poses.latest_xy()))
        return None if goal is None else goal_bytes(goal, stamp)

    def ask(self, request: dict[str, Any]) -> dict[str, Any]:
        """`ravenmem_msgs/srv/Ask` (request and response as dicts)."""
        return ask_reply(self.backend, request)

    def search(self, request: dict[str, Any]) -> dict[str, Any]:
        """`ravenmem_msgs/srv/Search` (request and response as dicts)."""
        return search_reply(self.backend, request)


class LinkNode:
    """Subscribes to the link's topics with raw (CDR) callbacks that feed `NodeLogic`, publishes
    goals and serves Ask and Search. rclpy's default executor runs callbacks one at a time, so
    the RosLink has one caller, as in the Zenoh link."""

    def __init__(self, cfg: LinkConfig, service: Service, name: str = "ravenmem") -> None:
        rclpy, qos, utils = _ros()
        from rclpy.node import Node
        from rosidl_runtime_py.convert import message_to_ordereddict
        from rosidl_runtime_py.set_message import set_message_fields

        self.logic = NodeLogic(cfg, service)
        self.node: Any = Node(name)
        types = dict(self.node.get_topic_names_and_types())

        def msg_class(key: str, given: str | None, default: str) -> Any:
            found = types.get(topic(key), [])
            return utils.get_message(given or (found[0] if found else default))

        link = self.logic.link
        img_cls = msg_class(cfg.image, cfg.image_type, msgs.IMAGE)
        pose_cls = msg_class(cfg.pose, cfg.pose_type, msgs.TF if cfg.tf else msgs.ODOMETRY)
        sensor = qos.qos_profile_sensor_data
        self.node.create_subscription(
            img_cls, topic(cfg.image), lambda raw: link.image(cfg.image, raw), sensor, raw=True
        )
        self.node.create_subscription(
            pose_cls, topic(cfg.pose), lambda raw: link.pose(cfg.pose, raw), 100, raw=True
        )
        if cfg.tf_static_key:
            latched = qos.QoSProfile(depth=100, durability=qos.DurabilityPolicy.TRANSIENT_LOCAL)
            key = cfg.tf_static_key
            tf_cls = utils.get_message(msgs.TF)
            self.node.create_subscription(
                tf_cls, topic(key), lambda raw: link.pose(key, raw), latched, raw=True
            )
        self.goal_pub = None
        if cfg.goal:
            self.goal_pub = self.node.create_publisher(
                utils.get_message(msgs.POSE_STAMPED), topic(cfg.goal), 10
            )
        if cfg.services:
            for service_name, answer in (("ask", self.logic.ask), ("search", self.logic.search)):

                def callback(request: Any, response: Any, answer: Any = answer) -> Any:
                    set_message_fields(response, answer(dict(message_to_ordereddict(request))))
                    return response

                srv = utils.get_service(f"ravenmem_msgs/srv/{service_name.title()}")
                self.node.create_service(srv, f"/{cfg.services}/{service_name}", callback)
        self.node.create_timer(TICK_S, link.tick)

    def on_answer(self, result: AskResult) -> None:
        """The service's answer hook: publish the result's goal (when there is a goal topic)."""
        payload = self.logic.goal(result) if self.goal_pub is not None else None
        if payload is not None and self.goal_pub is not None:
            self.goal_pub.publish(payload)
            self.logic.link.stats.add("goals")

    def describe(self) -> dict[str, Any]:
        return {"kind": "rclpy", "frame_id": self.logic.link.poses.frame} | self.logic.link.stats.as_dict()

    def close(self) -> None:
        self.logic.link.flush()


def main(argv: list[str] | None = None) -> None:
    """Run the node on a memory until Ctrl-C: frames through the service's one live writer."""
    ap = argparse.ArgumentParser(prog="python -m ravenmem.ros.node", description=__doc__)
    ap.add_argument("--memory", required=True, help="memory folder (created when missing)")
    ap.add_argument(
        "--link", required=True, help="image=TOPIC,pose=TOPIC[,key=value...] as for serve --zenoh"
    )
    ap.add_argument(
        "--keyframes", default=None, help="keyframe rules as for ingest (default: the default rules; 'all')"
    )
    ap.add_argument("--map-id", default=None, help="the map the poses are in (see ravenmem align)")
    args = ap.parse_args(argv)
    share_cores()  # before torch or FAISS loads (ravenmem.threads)
    cfg = LinkConfig.from_spec(args.link)
    rclpy, _, _ = _ros()
    import ravenmem

    from ..ingest.keyframes import KeyframeConfig
    from ..memory.folder import is_memory
    from ..runtime.service import Service, ServiceConfig

    path = Path(args.memory)
    mem = ravenmem.open(path) if is_memory(path) else ravenmem.create(path)
    if args.map_id:
        mem.claim_map(args.map_id, what="--map-id")
    service = Service(mem, ServiceConfig(keyframes=KeyframeConfig.from_spec(args.keyframes))).start()
    rclpy.init()
    node = LinkNode(cfg, service)
    service.attach(node)
    try:
        rclpy.spin(node.node)
    except KeyboardInterrupt:
        pass
    finally:
        node.node.destroy_node()
        rclpy.shutdown()
        service.close()


if __name__ == "__main__":
    try:
        main()
    except RavenmemError as e:  # one line, as the ravenmem command prints it
        sys.stderr.write(f"error: {e}\n")
        sys.exit(2)
