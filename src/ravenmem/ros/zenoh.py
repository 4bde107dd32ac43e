"""The robot link over Zenoh (`ravenmem serve --zenoh`): subscribers feed the link's logic
(`ros.link.RosLink`), goals go out as PoseStamped CDR on the goal key (and, optionally, as a
NavigateToPose action: `ros.action`), and the memory answers `ravenmem_msgs/srv/Ask` and
`Search` as queryables under the key names that zenoh-bridge-ros2dds and rmw_zenoh give ROS 2
services (`ros.services`).

Threads: the subscriber callbacks only queue the bytes; one worker thread decodes, pairs and
calls the sink (which may block while a frame is stored), so Zenoh's threads never wait on the
embedder. Service queries are answered on their own worker (a question may take a model call).
"""

from __future__ import annotations

import contextlib
import json
import logging
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ..errors import InputError, one_line, require
from .link import SKIP_BUSY, LinkConfig, LinkStats, RosLink, Sink, goal_bytes, goal_of, writer_sink
from .services import Backend, ServiceBackend, bridge_token, handle, keys, rmw_reply_attachment

if TYPE_CHECKING:
    from ..agent.ask import AskResult, PlanLike
    from ..nav.goals import GoalPlan
    from ..runtime.service import Service
    from .action import NavigateClient

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ZenohEndpoints:
    """How the link's Zenoh session finds the robot: a Zenoh JSON5 config file (routers, TLS,
    namespaces), plus connect/listen endpoints such as `tcp/192.168.1.10:7447`. With explicit
    endpoints multicast scouting is off (the robot is where you said); without, Zenoh's defaults
    apply (peer mode, multicast scouting on the local network)."""

    connect: tuple[str, ...] = ()
    listen: tuple[str, ...] = ()
    config_file: Path | None = None

    def config(self) -> Any:
        zenoh: Any = require("zenoh", "robot")
        try:
            conf = zenoh.Config.from_file(str(self.config_file)) if self.config_file else zenoh.Config()
        except Exception as e:  # zenoh raises its own ZError for unreadable or invalid files
            raise InputError(f"zenoh config {self.config_file}: {short_error(e)}") from None
        if self.connect or self.listen:
            conf.insert_json5("scouting/multicast/enabled", "false")
            conf.insert_json5("scouting/gossip/enabled", "false")
        try:
            if self.connect:
                conf.insert_json5("connect/endpoints", json.dumps(list(self.connect)))
            if self.listen:
                conf.insert_json5("listen/endpoints", json.dumps(list(self.listen)))
        except Exception as e:
            raise InputError(
                f"zenoh endpoints {list(self.connect) + list(self.listen)}: {short_error(e)}"
            ) from None
        return conf

    def open(self) -> Any:
        """A Zenoh session, or a one-line InputError."""
        zenoh: Any = require("zenoh", "robot")
        try:
            return zenoh.open(self.config())
        except InputError:
            raise
        except Exception as e:
            raise InputError(f"zenoh: cannot open a session ({short_error(e)})") from None


def short_error(e: BaseException) -> str:
    """Zenoh's error text on one line, without the Rust source location it appends."""
    text = one_line(e)
    return text.split(" at /", 1)[0][:300]


# What plans the goal of a result that asked for none (from the robot's latest pose).
Planner = Callable[["AskResult", "tuple[float, float] | None"], "PlanLike | None"]


class ZenohLink:
    """`RosLink` behind Zenoh subscribers, the goal publisher and the service queryables. At
    most `max_queued_images` images wait in the queue; beyond that the newest is dropped and
    counted (`SKIP_BUSY`) rather than memory growing."""

    def __init__(
        self,
        cfg: LinkConfig,
        sink: Sink,
        endpoints: ZenohEndpoints | None = None,
        max_queued_images: int = 16,
        backend: Backend | None = None,
        planner: Planner | None = None,
        frame_check: Callable[[str], str | None] | None = None,
    ) -> None:
        self.cfg = cfg
        self.link = RosLink(cfg, sink, frame_check=frame_check)
        self.endpoints = endpoints or ZenohEndpoints()
        self.max_queued_images = max_queued_images
        self.backend = backend
        self.planner = planner
        self._queue: queue.Queue[tuple[str, str, bytes, float] | None] = queue.Queue(maxsize=10_000)
        self._queries: queue.Queue[tuple[str, Any] | None] = queue.Queue(maxsize=64)
        self._images_queued = 0
        self._lock = threading.Lock()
        self.session: Any = None
        self._subs: list[Any] = []
        self._tokens: list[Any] = []
        self._goal_pub: Any = None
        self._threads: list[threading.Thread] = []
        self.action: NavigateClient | None = None
        self.last_drive: dict[str, Any] | None = None

    @property
    def stats(self) -> LinkStats:
        return self.link.stats

    def start(self) -> ZenohLink:
        """Open the session, declare the subscribers, the goal publisher and the services, and
        start the workers."""
        self.session = self.endpoints.open()
        try:
            for role, key in (("image", self.cfg.image), ("pose", self.cfg.pose)):
                self._subs.append(self.session.declare_subscriber(key, self._callback(role)))
            if self.cfg.tf_static_key:
                self._subs.append(self._latched(self.cfg.tf_static_key, self._callback("pose")))
            if self.cfg.goal:
                self._goal_pub = self.session.declare_publisher(self.cfg.goal)
            if self.cfg.action:
                from .action import NavigateClient

                self.action = NavigateClient(self.session, self.cfg.action)
            if self.cfg.services and self.backend is not None:
                self._declare_services(self.cfg.services)
        except InputError:
            self.close()
            raise
        except Exception as e:
            self.close()
            raise InputError(f"zenoh: cannot subscribe ({short_error(e)})") from None
        for target, name in ((self._run, "ravenmem-zenoh"), (self._answer, "ravenmem-zenoh-services")):
            th = threading.Thread(target=target, name=name, daemon=True)
            th.start()
            self._threads.append(th)
        return self

    def _declare_services(self, name: str) -> None:
        zid = str(self.session.zid())
        for service in ("ask", "search"):
            for key in keys(name, service, self.cfg.domain):
                self._subs.append(self.session.declare_queryable(key, self._on_query(service)))
            with contextlib.suppress(Exception):  # an announcement for bridges; serving works without
                self._tokens.append(self.session.liveliness().declare_token(bridge_token(zid, name, service)))
        log.info("robot link: ravenmem_msgs services on %s/ask and %s/search", name, name)

    def _on_query(self, service: str) -> Callable[[Any], None]:
        def on_query(query: Any) -> None:
            try:
                self._queries.put_nowait((service, query))
            except queue.Full:
                with contextlib.suppress(Exception):
                    query.reply_err("ravenmem: too many questions at once; ask again")

        return on_query

    def _answer(self) -> None:
        """The services' worker: one query at a time, replied with the CDR reply."""
        while True:
            item = self._queries.get()
            if item is None:
                break
            service, query = item
            try:
                payload = query.payload.to_bytes() if query.payload is not None else b""
                att = query.attachment.to_bytes() if query.attachment is not None else None
                assert self.backend is not None
                reply = handle(service, self.backend, payload)
                self.link.stats.add("questions")
                kw = {"attachment": a} if (a := rmw_reply_attachment(att)) is not None else {}
                query.reply(query.key_expr, reply, **kw)
            except Exception:
                log.exception("robot link: answering a %s query failed", service)
            finally:
                with contextlib.suppress(Exception):
                    query.drop()

    def _latched(self, key: str, callback: Callable[[Any], None]) -> Any:
        """A subscriber that also fetches what was published before it joined (/tf_static is
        "transient local" in ROS 2: sent once, at start-up). Zenoh's advanced subscriber asks
        the caches of advanced publishers (rmw_zenoh's and the bridge's transient-local
        publishers keep one); where that API is missing, a plain subscriber."""
        zenoh: Any = require("zenoh", "robot")
        ext = getattr(zenoh, "ext", None)
        try:
            history = ext.HistoryConfig(detect_late_publishers=True)  # type: ignore[union-attr]
            return ext.declare_advanced_subscriber(self.session, key, callback, history=history)  # type: ignore[union-attr]
        except Exception as e:  # an older zenoh, or one built without the unstable API
            log.warning("robot link: no history for %s (%s); start the link before the robot", key, e)
            return self.session.declare_subscriber(key, callback)

    def _callback(self, role: str) -> Callable[[Any], None]:
        stats = self.link.stats

        def on_sample(sample: Any) -> None:
            recv = time.time()
            if role == "image":
                with self._lock:
                    busy = self._images_queued >= self.max_queued_images
                    self._images_queued += 0 if busy else 1
                if busy:
                    stats.add("images")
                    stats.skip(SKIP_BUSY)
                    return
            try:
                self._queue.put_nowait((role, str(sample.key_expr), sample.payload.to_bytes(), recv))
            except queue.Full:
                stats.skip(SKIP_BUSY)
                if role == "image":
                    with self._lock:
                        self._images_queued -= 1

        return on_sample

    def _run(self) -> None:
        """The worker: the only caller of the RosLink (which is therefore never used concurrently)."""
        while True:
            try:
                item = self._queue.get(timeout=0.1)
            except queue.Empty:
                self.link.tick()
                continue
            if item is None:
                break
            role, key, payload, recv = item
            try:
                if role == "image":
                    with self._lock:
                        self._images_queued -= 1
                    self.link.image(key, payload, recv)
                else:
                    self.link.pose(key, payload, recv)
            except Exception:  # one bad message must not stop the link
                log.exception("robot link: handling a message on %s failed", key)
        self.link.flush()

    # ---------------------------------------------------------------- goals
    def robot_xy(self) -> tuple[float, float] | None:
        """The robot's latest position from the pose stream (the start of a plan), or None."""
        return self.link.poses.latest_xy()

    def publish_goal(self, result: AskResult) -> bool:
        """Send the goal of an answer's plan (`nav.goals.goal_for`, planned now from the robot's
        latest pose when the question asked for none): on the goal key, and to the
        NavigateToPose action when configured. False when there is no goal to send."""
        if self._goal_pub is None and self.action is None:
            return False
        plan = result.plan
        if plan is None and self.planner is not None:
            plan = self.planner(result, self.robot_xy())
        goal = goal_of(plan) if result.refusal is None else None
        if goal is None:
            return False
        if self._goal_pub is not None:
            self._goal_pub.put(goal_bytes(goal, time.time()))
        if self.action is not None and result.drive is None:  # (an answer driven to already)
            self.last_drive = {"status": "sent", "goal": goal}
            threading.Thread(target=self.drive, args=(goal,), name="ravenmem-drive", daemon=True).start()
        self.link.stats.add("goals")
        return True

    def drive(self, goal: dict[str, Any]) -> dict[str, Any] | None:
        """Drive to a goal with the NavigateToPose action and wait for its result (None when no
        action is configured); the result is also `describe()["last_drive"]`."""
        if self.action is None:
            return None
        self.last_drive = result = self.action.drive(goal)
        return result

    def on_answer(self, result: AskResult) -> None:
        """The service's answer hook (a result that may be used): its plan's goal is sent."""
        self.publish_goal(result)

    def describe(self) -> dict[str, Any]:
        """What `/info` shows under `links`: the keys, the frame and the counts."""
        keys_ = {"image": self.cfg.image, "pose": self.cfg.pose, "tf_static": self.cfg.tf_static_key}
        out: dict[str, Any] = {"kind": "zenoh", **keys_, "goal": self.cfg.goal, "waiting": self.link.waiting}
        out |= {"services": self.cfg.services, "action": self.cfg.action, "frame_id": self.link.poses.frame}
        if self.cfg.tf:  # which frame the poses are in, or why none could be found yet
            out["tf_parent"], out["tf_note"] = self.link.poses.parent, self.link.poses.tf_note
        if self.last_drive is not None:
            out["last_drive"] = self.last_drive
        return out | self.stats.as_dict()

    def close(self, timeout: float = 30.0) -> None:
        """Stop taking messages and questions, settle what is queued, then close the session."""
        if self.action is not None:
            self.action.close()
        for sub in self._subs:
            with contextlib.suppress(Exception):
                sub.undeclare()
        for tok in self._tokens:
            with contextlib.suppress(Exception):
                tok.undeclare()
        self._subs, self._tokens = [], []
        if self._threads:
            self._queue.put(None)
            self._queries.put(None)
            for th in self._threads:
                th.join(timeout)
            self._threads = []
        if self.session is not None:
            with contextlib.suppress(Exception):
                self.session.close()
            self.session = None


def start_link(service: Service, cfg: LinkConfig, endpoints: ZenohEndpoints | None = None) -> ZenohLink:
    """Start the robot link on a service (`ravenmem serve --zenoh`): frames into its writer,
    answers with a plan out as goals, the memory's services answered; closed with the service."""
    if service.writer is None:
        raise InputError("--zenoh adds frames to the memory: it cannot run with --read-only")
    service.start()
    holder: list[ZenohLink] = []

    def start() -> tuple[float, float] | None:
        return holder[0].robot_xy() if holder else None

    def planner(result: AskResult, xy: tuple[float, float] | None) -> GoalPlan | None:
        return service.plan_of(result, xy)

    def drive(goal: dict[str, Any]) -> dict[str, Any] | None:
        return holder[0].drive(goal) if holder else None

    link = ZenohLink(
        cfg,
        writer_sink(service.writer, cfg.source),
        endpoints,
        backend=ServiceBackend(service, start, drive if cfg.action else None),
        planner=planner,
        frame_check=service.frame_check,
    )
    holder.append(link)
    link.start()
    service.attach(link)
    log.info(
        "robot link: images on %s, poses on %s%s",
        cfg.image,
        cfg.pose,
        f", goals on {cfg.goal}" if cfg.goal else "",
    )
    return link
