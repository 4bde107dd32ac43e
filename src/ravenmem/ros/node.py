"""ravenmem as a ROS 2 node (rclpy): what `ravenmem ros run` runs (the process: `ros.run`).

    ravenmem ros setup                      # once: builds ravenmem_msgs into this environment
    ravenmem ros run --memory robot.mem --create --ros-args \\
        -p image_topic:=/camera/color/image_raw -p odom_topic:=/odom -r __ns:=/bot1

Node `ravenmem`; every setting a declared ROS parameter (`ros.params.NodeSettings`), so `-p`,
`--params-file`, remaps and `use_sim_time` work as for any ROS 2 node. Inputs: images (raw or
compressed, `auto`: chosen once a publisher is discovered), odometry or /tf + /tf_static, the
CameraInfo (kept in the memory's manifest), the OccupancyGrid on `map_topic` (the memory's map
for goal planning). Callbacks never wait on the embedder or the disk: images go through
`ros.intake.FrameIntake` into the runtime's one `LiveWriter`, and every image is accounted for
(published on /diagnostics), even one that never reached it (a gap in its publisher's
sequence numbers). Outputs: services `~/ask` and `~/search` (`ravenmem_msgs`, the
replies of `ros.services`), the action `~/ask_action` (a feedback per tool call, cancellable), a
goal on `goal_topic` (or through Nav2's NavigateToPose when `navigate_action` is set) only for a
question that asks to navigate, MarkerArrays on `~/markers`. SIGINT and SIGTERM stop the intake,
store what was queued and exit 0. `--lifecycle`: the same node as a managed (lifecycle) node,
brought up through configure and activate (`ros.lifecycle`). The process around either (arguments,
rclpy, signals) is `ros.run`.

`NodeLogic` is the older transport-free form over `ros.link.RosLink` (CDR in, CDR out), kept for
the front ends' comparison test.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..errors import InputError, one_line
from . import msgs
from .convert import fill, to_dict
from .intake import FrameIntake
from .link import LinkConfig, RosLink, goal_bytes, goal_of, writer_sink
from .outputs import RateLimitedLog, answer_markers, diagnostics, memory_markers
from .params import NodeSettings
from .services import ServiceBackend, ask_reply, search_reply

if TYPE_CHECKING:
    from ..agent.ask import AskResult
    from ..runtime.service import Service

TICK_S = 0.1  # how often waiting images are settled


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


class RavenmemNode:
    """The rclpy node around a running `Service` (see the module docstring). Pose and map
    callbacks run one at a time (one mutually exclusive group), each camera's images in a group
    of its own (the intake takes its own lock), so an image is never queued behind the poses
    and the subscription's history does not fill up; services, the action and NavigateToPose
    waits run in a reentrant group on the executor's other threads.

    A managed node (`ros.lifecycle`) makes it at `configure` with `subscribe` False (the inputs
    come at `activate`) and its own `sensors` group, the one its transitions run in, so that no
    pose callback or settling tick runs during a transition."""

    def __init__(
        self,
        node: Any,
        settings: NodeSettings,
        service: Service,
        subscribe: bool = True,
        sensors: Any = None,
    ) -> None:
        from rclpy.callback_groups import MutuallyExclusiveCallbackGroup, ReentrantCallbackGroup

        assert service.writer is not None
        self.node, self.s, self.service = node, settings, service
        self.log = RateLimitedLog(node.get_logger().warning)
        self.intake = FrameIntake(service.writer, settings, service.frame_check, self.log)
        self.sensors = sensors if sensors is not None else MutuallyExclusiveCallbackGroup()
        self.answers = ReentrantCallbackGroup()
        self.camera_info: dict[str, Any] | None = None
        self.image_subs: list[Any] = []
        self.transport: str | None = None
        self._local = threading.local()
        self._markers_count = -1
        self.goals = 0
        self.navigator = None
        if settings.navigate_action:
            from .navigate import Navigator

            self.navigator = Navigator(node, settings.navigate_action, self.answers)
        drive = self.navigator.drive if self.navigator is not None else None
        self.backend = ServiceBackend(service, self.intake.latest_xy, drive)
        if subscribe:
            self.subscribe_inputs()
        self._publish_and_serve()

    # ---------------------------------------------------------------- wiring
    def _qos(self, name: str, depth: int = 10) -> Any:
        from rclpy.qos import QoSProfile, ReliabilityPolicy, qos_profile_sensor_data

        if name == "sensor_data":  # best effort, volatile, at the depth asked for
            return QoSProfile(
                depth=depth,
                reliability=qos_profile_sensor_data.reliability,
                durability=qos_profile_sensor_data.durability,
            )
        rel = ReliabilityPolicy.RELIABLE if name == "reliable" else ReliabilityPolicy.BEST_EFFORT
        return QoSProfile(depth=depth, reliability=rel)

    def _timer(self, period: float, callback: Any, group: Any) -> Any:
        """A housekeeping timer on the steady clock: it runs while simulated time is paused."""
        from rclpy.clock import Clock, ClockType

        return self.node.create_timer(period, callback, group, clock=Clock(clock_type=ClockType.STEADY_TIME))

    def _latched(self, depth: int) -> Any:
        from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy

        return QoSProfile(
            depth=depth, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
        )

    def subscribe_inputs(self) -> None:
        """The inputs: poses, camera info, map, the cameras (now, or once discovered), the tick."""
        from nav_msgs.msg import OccupancyGrid, Odometry
        from sensor_msgs.msg import CameraInfo

        s, sub = self.s, self.node.create_subscription
        if s.odom_topic:
            sub(
                Odometry,
                s.odom_topic,
                lambda m: self.intake.odometry(m, self.now()),
                self._qos(s.pose_qos, 100),
                callback_group=self.sensors,
            )
        else:
            from tf2_msgs.msg import TFMessage

            sub(
                TFMessage,
                "/tf",
                lambda m: self.intake.transforms(m, self.now(), False),
                self._qos(s.pose_qos, 100),
                callback_group=self.sensors,
            )
            sub(
                TFMessage,
                "/tf_static",
                lambda m: self.intake.transforms(m, self.now(), True),
                self._latched(100),
                callback_group=self.sensors,
            )
        if s.camera_info_topic:
            sub(
                CameraInfo,
                s.camera_info_topic,
                self._on_camera_info,
                self._qos("sensor_data"),
                callback_group=self.sensors,
            )
        if s.map_topic:
            sub(OccupancyGrid, s.map_topic, self._on_map, self._latched(1), callback_group=self.sensors)
        self._unresolved = list(s.cameras)
        if s.image_transport == "auto":
            self._discover = self._timer(0.2, self._resolve_transport, self.sensors)
        else:
            for cam in s.cameras:
                self._subscribe_images(s.image_transport, self.node.resolve_topic_name(cam), cam)
        self._timer(TICK_S, self.intake.settle, self.sensors)

    def _resolve_transport(self) -> None:
        """`auto`: each camera's type once a publisher is on the graph (raw on the topic, or
        compressed on it or on `<topic>/compressed`)."""
        types = dict(self.node.get_topic_names_and_types())
        for cam in list(self._unresolved):
            base = self.node.resolve_topic_name(cam)
            if msgs.IMAGE in types.get(base, []):
                self._subscribe_images("raw", base, cam)
            elif msgs.COMPRESSED in types.get(base, []):
                self._subscribe_images("compressed", base, cam)
            elif msgs.COMPRESSED in types.get(base + "/compressed", []):
                self._subscribe_images("compressed", base + "/compressed", cam)
            else:
                continue
            self._unresolved.remove(cam)
        if not self._unresolved:
            self._discover.cancel()

    def _subscribe_images(self, transport: str, topic_name: str, camera: str) -> None:
        from rclpy.callback_groups import MutuallyExclusiveCallbackGroup
        from sensor_msgs.msg import CompressedImage, Image

        if (
            transport == "compressed"
            and not topic_name.endswith("/compressed")
            and self.s.image_transport != "auto"
        ):
            topic_name += "/compressed"  # image_transport's naming
        cls, kind = (CompressedImage, msgs.COMPRESSED) if transport == "compressed" else (Image, msgs.IMAGE)
        self.transport = ", ".join(filter(None, (self.transport, f"{transport} on {topic_name}")))
        self.node.get_logger().info(f"images: {transport} on {topic_name}")
        source = self.s.source_of(camera)
        from rclpy.event_handler import SubscriptionEventCallbacks

        # an image that never reached the node is counted: a gap in its publisher's sequence
        # numbers (a history that overflowed while the node was busy: DDS says nothing), and
        # what the middleware itself reports lost
        events = SubscriptionEventCallbacks(message_lost=self._lost)

        def take(msg: Any, info: Any) -> None:
            gid = info.get("publisher_gid")
            publisher = None if gid is None else str(gid)
            self.intake.image(
                msg, kind, self.now(), source, publisher, info.get("publication_sequence_number")
            )

        self.image_subs.append(
            self.node.create_subscription(
                cls,
                topic_name,
                take,
                self._qos(self.s.image_qos, self.s.image_depth),
                callback_group=MutuallyExclusiveCallbackGroup(),
                event_callbacks=events,
            )
        )

    def _lost(self, info: Any) -> None:
        n = int(info.total_count_change)
        self.intake.counts.missed(n, reported=True)
        self.log(f"{n} image(s) lost in transport (reported by DDS)")

    def _publish_and_serve(self) -> None:
        from diagnostic_msgs.msg import DiagnosticArray
        from geometry_msgs.msg import PoseStamped
        from ravenmem_msgs.srv import Ask, Search
        from visualization_msgs.msg import MarkerArray

        s, node = self.s, self.node
        self.goal_pub = node.create_publisher(PoseStamped, s.goal_topic, 10) if s.goal_topic else None
        self.diag_pub = node.create_publisher(DiagnosticArray, "/diagnostics", 10)
        self.marker_pub = node.create_publisher(MarkerArray, "~/markers", self._latched(10))
        node.create_service(Ask, "~/ask", self._ask, callback_group=self.answers)
        node.create_service(Search, "~/search", self._search, callback_group=self.answers)
        self._timer(s.diagnostics_period, self._diagnostics, self.answers)
        if s.markers_period > 0:
            self._timer(s.markers_period, self._memory_markers, self.answers)
        from .ask_action import AskAction

        self.ask_action = AskAction(self, self.answers)

    # ---------------------------------------------------------------- callbacks
    def now(self) -> float:
        """The node's clock (ROS time: simulated time with use_sim_time) in seconds."""
        return float(self.node.get_clock().now().nanoseconds) * 1e-9

    def stamp(self) -> Any:
        return self.node.get_clock().now().to_msg()

    def drop_answers_on_this_thread(self, canceled: Callable[[], bool] | None) -> None:
        """While `canceled()` is true, `on_answer` publishes nothing for answers given on the
        calling thread (a canceled question action's; None ends it)."""
        self._local.canceled = canceled

    def _on_camera_info(self, msg: Any) -> None:
        why = self.intake.camera_info_ok(msg)
        if why is not None:
            self.intake._bad(why)
            return
        self.camera_info = {
            "frame_id": msg.header.frame_id,
            "width": int(msg.width),
            "height": int(msg.height),
            "distortion_model": msg.distortion_model,
            "k": [float(v) for v in msg.k],
            "d": [float(v) for v in msg.d],
        }

    def _on_map(self, msg: Any) -> None:
        """The live map (map_server, SLAM) becomes the memory's map, as `map --import-nav2` does."""
        from ..errors import InputError
        from .nav2 import grid_from_occupancy

        info, o = msg.info, msg.info.origin
        yaw = (
            2 * math.atan2(float(o.orientation.z), float(o.orientation.w))
            if o.orientation.w or o.orientation.z
            else 0.0
        )
        try:
            grid = grid_from_occupancy(
                int(info.width),
                int(info.height),
                float(info.resolution),
                (float(o.position.x), float(o.position.y), yaw),
                msg.data,
                f"{self.node.resolve_topic_name(self.s.map_topic)} (nav_msgs/OccupancyGrid)",
            )
            grid.save(self.service.mem.path)
        except InputError as e:
            self.intake._bad(str(e))
            return
        self.node.get_logger().info(f"map: {info.width}x{info.height} cells at {info.resolution} m")

    def _ask(self, request: Any, response: Any) -> Any:
        reply = ask_reply(self.backend, to_dict(request))
        fill(response, reply)
        if response.goal.header.frame_id:
            response.goal.header.stamp = self.stamp()
        return response

    def _search(self, request: Any, response: Any) -> Any:
        return fill(response, search_reply(self.backend, to_dict(request)))

    def on_answer(self, result: AskResult) -> None:
        """The service's answer hook (the one goal path): a goal only for a result whose
        question asked to navigate (it carries a plan) and whose plan found a path; markers for
        every answer the service hands on (the ones that may be used)."""
        canceled = getattr(self._local, "canceled", None)
        if canceled is not None and canceled():
            return
        goal = result.goal  # None without a plan (no navigate), or a plan with no path
        frame = self.service.mem.frame_id or self.s.map_frame
        self.marker_pub.publish(answer_markers(self.stamp(), frame, result.answer, goal))
        if goal is None or self.goal_pub is None or self.navigator is not None:
            return
        from geometry_msgs.msg import PoseStamped

        msg = fill(PoseStamped(), goal)
        msg.header.stamp = self.stamp()
        self.goal_pub.publish(msg)
        self.goals += 1

    def _diagnostics(self) -> None:
        self.diag_pub.publish(diagnostics(self.stamp(), self.counts()))

    def _memory_markers(self) -> None:
        traj = self.service.trajectory(20_000)
        if traj["count"] == self._markers_count:
            return
        self._markers_count = traj["count"]
        frame = self.service.mem.frame_id or self.s.map_frame
        self.marker_pub.publish(memory_markers(self.stamp(), frame, traj["points"]))

    def counts(self) -> dict[str, Any]:
        return self.intake.counts.as_dict(len(self.intake.waiting)) | {"goals": self.goals}

    # ---------------------------------------------------------------- the service's link protocol
    def describe(self) -> dict[str, Any]:
        return {
            "kind": "rclpy",
            "node": self.node.get_fully_qualified_name(),
            "transport": self.transport,
        } | self.counts()

    def stop_intake(self) -> None:
        """Stop taking frames and hand the waiting ones to the writer (SIGINT/SIGTERM, a managed
        node's cleanup; `close`)."""
        self.intake.stopping = True  # images still delivered are counted as SKIP_STOPPING
        self.intake.settle(flush=True)

    def finish(self) -> None:
        """Store what was queued, note the run in the manifest and close the memory (its writer
        lock released). The caller has stopped the intake first (`stop_intake`, or the managed
        node's deactivate), so no image waits for a writer that is closed."""
        assert self.service.writer is not None
        self.service.writer.close()  # stores what was queued
        self.record()
        self.service.close()

    def close(self) -> None:
        """Called by `Service.close` before the writer closes: flush, note the run in the
        manifest (the counts, the CameraInfo)."""
        self.stop_intake()

    def record(self) -> None:
        """After the writer stored everything: the run's counts and camera into the manifest."""
        report = {"source": "ros", "node": self.node.get_fully_qualified_name(), "counts": self.counts()}
        if self.camera_info is not None:
            report["camera_info"] = self.camera_info
        try:
            self.service.mem.record_ingest(report)
        except OSError:
            self.node.get_logger().error("could not note the run in the memory's manifest")


def open_service(memory: Path, create: bool, s: NodeSettings) -> Service:
    """The running service over the memory (created when missing with `create`), its writer
    lock held."""
    import ravenmem

    from ..agent.config import VLMConfig
    from ..errors import InputError
    from ..ingest.keyframes import KeyframeConfig
    from ..memory.folder import is_memory
    from ..runtime.service import Service, ServiceConfig

    if not is_memory(memory) and not create:
        raise InputError(f"no memory at {memory} (give --create to start one)")
    vlm = VLMConfig.resolve(base_url=s.base_url or None, model=s.model or None)
    cfg = ServiceConfig(
        keyframes=KeyframeConfig.from_spec(s.keyframes or None), method=s.method or None, vlm=vlm
    )  # checked before the memory is touched
    mem = ravenmem.open(memory) if is_memory(memory) else ravenmem.create(memory)
    try:
        return Service(mem, cfg).start()
    except BaseException:  # another writer holds it: closed again (a managed node may retry)
        mem.close()
        raise


def made_node(make: Callable[[], Any]) -> Any:
    """The node `make()` makes; an invalid remapped name or namespace is a one-line
    `InputError` (and rclpy is shut down)."""
    import rclpy

    try:
        return make()
    except Exception as e:
        rclpy.shutdown()
        raise InputError(f"--ros-args: {one_line(e)}") from None
