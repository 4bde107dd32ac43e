"""The robot link: a ROS 2 camera and pose stream over Zenoh into a live memory, and answers back
to the robot's planner as a goal pose.

ROS 2 robots reach other processes over Zenoh: `zenoh-bridge-ros2dds` publishes each topic's CDR
bytes on a key named after the topic (`/camera/color/image_raw` on `camera/color/image_raw`), and
`rmw_zenoh` publishes on `<domain>/<topic>/<type>/<hash>` keys. The link subscribes to one image
key and one pose key (nav_msgs/Odometry, geometry_msgs/PoseStamped or
PoseWithCovarianceStamped, or /tf plus /tf_static), decodes the CDR with `rosbags` through the
same converters as the bag source (`ingest.rosmsg`), poses each image at its stamp from the
recent poses (interpolated, or the nearest within a gap, as `ingest.poses.PoseTrack` does for
bags) and hands (RGB, pose, time) to a sink: the service's one writer, which runs the online
keyframe rule and stores. Every frame that does not become a memory is counted with its reason.

An image newer than the newest pose waits (at most `wait` seconds, at most `max_pending`
images) for the poses that bracket it; odometry usually lags the camera a little. Nothing is
guessed: an image whose pose never comes is counted as `SKIP_NO_POSE`.

`RosLink` is the logic, fed message by message, with no Zenoh in it (tests and the rclpy node
use it directly); `ZenohLink` runs it behind Zenoh subscribers on one worker thread.
"""

from __future__ import annotations

import bisect
import contextlib
import json
import logging
import math
import queue
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import TimeoutError as FutureTimeout
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import InputError, require
from ..ingest import rosmsg
from ..ingest._tf import TfTree, norm_frame
from ..ingest.poses import PoseTrack, check_match_mode
from ..types import Pose

if TYPE_CHECKING:
    from .live import LiveWriter
    from .service import Service

log = logging.getLogger(__name__)

SKIP_NO_POSE = "no pose in time"  # the pose stream is late, stopped or never started
SKIP_BUSY = "link busy: frame dropped before storing"
SKIP_TYPE = "undecodable message"  # not CDR of any type this key may carry
SKIP_SLOW = "not stored in time"  # the writer did not answer within its timeout

# What a sink does with a posed frame: the new memory's id, or the reason it was not kept.
Sink = Callable[[np.ndarray, Pose, float], "int | str"]


@dataclass(frozen=True)
class LinkConfig:
    """What to subscribe to and how to pair images with poses.

    image / pose: Zenoh key expressions of the image topic and of the pose topic (or /tf).
    image_type / pose_type: the ROS type when the key does not say (None: the type an rmw_zenoh
    key names, else the first candidate type the first message decodes as, then kept).
    tf_static: key of /tf_static (default `tf_static` when the pose key carries TF).
    parent / child: TF frames; parent None picks map, odom or world, the first that is an
    ancestor of child. match / max_gap: as the bag source (interpolate, or nearest within
    max_gap s; 0.05 s by default with nearest). time: `header` (header.stamp, receive time
    when zero) or `receive`. wait: seconds an image waits for a later pose; max_pending: images
    that may wait at once; history: seconds of poses kept. goal / goal_frame: key and frame of
    the goal pose published after an answer with a position. source: the memories' source name.
    """

    image: str
    pose: str
    image_type: str | None = None
    pose_type: str | None = None
    tf_static: str | None = None
    parent: str | None = None
    child: str = "base_link"
    match: str = "interpolate"
    max_gap: float | None = None
    time: str = "header"
    wait: float = 1.0
    max_pending: int = 64
    history: float = 30.0
    goal: str | None = None
    goal_frame: str = "map"
    source: str = "zenoh"

    def __post_init__(self) -> None:
        for name in ("image", "pose", "tf_static", "goal"):
            v = getattr(self, name)
            if v is not None:
                object.__setattr__(self, name, check_key(v, name))
        for name, allowed in (
            ("image_type", rosmsg.IMAGE_TYPES),
            ("pose_type", (*rosmsg.POSE_TYPES, rosmsg.TF)),
        ):
            v = getattr(self, name)
            if v is None:
                continue
            full = rosmsg.type_name(v)
            if full not in allowed:
                short = ", ".join(t.rsplit("/", 1)[1] for t in allowed)
                raise InputError(f"zenoh: {name}={v!r} is not one of {short}")
            object.__setattr__(self, name, full)
        check_match_mode(self.match)
        if self.time not in ("header", "receive"):
            raise InputError(f"zenoh: time must be header or receive, got {self.time!r}")
        for name in ("max_gap", "wait", "history"):
            v = getattr(self, name)
            if v is not None and not (math.isfinite(v) and v >= 0):
                raise InputError(f"zenoh: {name} must be a finite number >= 0, got {v!r}")
        if self.max_pending < 1:
            raise InputError(f"zenoh: max_pending must be >= 1, got {self.max_pending}")
        if self.match == "nearest" and self.max_gap is None:
            object.__setattr__(self, "max_gap", 0.05)
        for name in ("child", "goal_frame", "source"):
            if not str(getattr(self, name)).strip():
                raise InputError(f"zenoh: {name} must not be empty")

    @property
    def tf(self) -> bool:
        """Whether poses come from the TF tree (said by pose_type, or by a key named tf)."""
        if self.pose_type is not None:
            return self.pose_type == rosmsg.TF
        return self.pose.rsplit("/", 1)[-1] == "tf" or rosmsg.type_from_key(self.pose) == rosmsg.TF

    @property
    def tf_static_key(self) -> str | None:
        return self.tf_static if self.tf_static is not None else ("tf_static" if self.tf else None)


def check_key(key: str, what: str) -> str:
    """A Zenoh key expression from a ROS topic name or key (the leading '/' of a topic dropped)."""
    k = str(key).strip().strip("/")
    if not k or "//" in k or any(c in k for c in " \t\n#?$,"):
        raise InputError(f"zenoh: {what}={key!r} is not a Zenoh key expression (e.g. camera/color/image_raw)")
    return k


_INTS = {"max_pending"}
_FLOATS = {"max_gap", "wait", "history"}


def parse_link_spec(spec: str, **overrides: Any) -> LinkConfig:
    """`image=camera/color/image_raw,pose=odom[,key=value...]` -> LinkConfig (keys: its fields)."""
    known = [f.name for f in fields(LinkConfig)]
    values: dict[str, Any] = {}
    for part in spec.split(","):
        if not part.strip():
            continue
        key, eq, raw = (s.strip() for s in part.partition("="))
        if not eq or not raw:
            raise InputError(f"zenoh: {part.strip()!r} is not key=value (keys: {', '.join(known)})")
        if key not in known:
            raise InputError(f"zenoh: unknown key {key!r}; choose from {', '.join(known)}")
        if key in values:
            raise InputError(f"zenoh: {key} is given twice")
        try:
            values[key] = int(raw) if key in _INTS else float(raw) if key in _FLOATS else raw
        except ValueError:
            raise InputError(f"zenoh: {key}={raw!r} is not a number") from None
    values.update({k: v for k, v in overrides.items() if v is not None})
    for need in ("image", "pose"):
        if need not in values:
            raise InputError(f"zenoh: {need}=KEY is missing (e.g. image=camera/color/image_raw,pose=odom)")
    return LinkConfig(**values)


class MessageTypes:
    """Which ROS type the messages on a key are: the configured one, the one an rmw_zenoh key
    names, or else the candidate a message decodes as exactly (rosbags checks the size, so the
    candidate types here do not mistake each other), tried first for the key's next message."""

    def __init__(self, candidates: tuple[str, ...], given: str | None = None) -> None:
        self.candidates = candidates
        self.given = given
        self.known: dict[str, str] = {}

    def decode(self, key: str, payload: bytes | memoryview) -> tuple[Any, str] | None:
        """(message, type) or None when the bytes are no candidate type."""
        fixed = self.given or rosmsg.type_from_key(key)
        if fixed is not None:
            if fixed not in self.candidates:
                return None
            try:
                return rosmsg.deserialize(payload, fixed), fixed
            except Exception:  # rosbags raises SerdeError and friends for bytes of another type
                return None
        last = self.known.get(key)
        for t in ([last] if last else []) + [c for c in self.candidates if c != last]:
            try:
                msg = rosmsg.deserialize(payload, t)
            except Exception:
                continue
            if t != last and (last is not None or len(self.known) < 1024):
                self.known[key] = t
            return msg, t
        return None


class PoseHistory:
    """The robot's recent poses, from a pose topic or the TF tree, looked up at an image's stamp."""

    def __init__(self, cfg: LinkConfig) -> None:
        self.cfg = cfg
        self._t: list[float] = []
        self._xyz: list[tuple[float, float, float]] = []
        self._quat: list[tuple[float, float, float, float]] = []
        self.tree: TfTree | None = TfTree() if cfg.tf else None
        self._track: PoseTrack | None = None
        self._dirty = False
        self.tf_note = ""
        self.parent = norm_frame(cfg.parent) if cfg.parent else None

    def add(self, sample: rosmsg.Sample) -> None:
        i = bisect.bisect_left(self._t, sample.t)
        if i < len(self._t) and self._t[i] == sample.t:  # a repeated stamp keeps the last sample
            self._xyz[i], self._quat[i] = sample.xyz, sample.quat
        else:
            self._t.insert(i, sample.t)
            self._xyz.insert(i, sample.xyz)
            self._quat.insert(i, sample.quat)
        cut = bisect.bisect_left(self._t, self._t[-1] - self.cfg.history) - 1
        if cut > 0:  # keep one sample before the window so its start still interpolates
            del self._t[:cut], self._xyz[:cut], self._quat[:cut]
        self._dirty = True

    def add_tf(self, tf: rosmsg.TfSample, static: bool) -> None:
        assert self.tree is not None
        self.tree.add(tf.parent, tf.child, tf.t, tf.xyz, tf.quat, static=static)
        if not static:
            self.tree.prune(tf.t - self.cfg.history)
        self._dirty = True

    def track(self) -> PoseTrack | None:
        """The poses known now as a track (rebuilt after new samples), or None when none yet."""
        if not self._dirty:
            return self._track
        self._dirty = False
        self._track = None
        if self.tree is None:
            if self._t:
                self._track = PoseTrack(self._t, self._xyz, self._quat, name=self.cfg.pose)
            return self._track
        child = norm_frame(self.cfg.child)
        parent = self.parent or self.tree.default_parent(child)
        if parent is None:
            self.tf_note = f"no map/odom/world ancestor of {child!r} in tf yet"
            return None
        try:
            self._track = self.tree.track(parent, child, name="tf")
        except InputError as e:  # not connected yet, or the moving edges do not overlap yet
            self.tf_note = str(e)
            return None
        if self.parent is None:  # chosen once: every memory of a run is in the same frame
            self.parent = parent
            log.info("zenoh link: poses of %s in %s (from tf)", child, parent)
        return self._track

    @property
    def newest(self) -> float | None:
        tr = self.track()
        return None if tr is None else tr.span[1]

    def lookup(self, t: float) -> Pose | str:
        """The pose at t, or why there is none (`SKIP_OUTSIDE`, `SKIP_GAP`, `SKIP_NO_POSE`)."""
        tr = self.track()
        if tr is None:
            return SKIP_NO_POSE
        return tr.match(t, check_match_mode(self.cfg.match), self.cfg.max_gap)


@dataclass
class LinkStats:
    """What the link received and what became of each image (thread-safe counts: the Zenoh
    callbacks and the worker both count)."""

    images: int = 0
    poses: int = 0
    stored: int = 0
    skipped: dict[str, int] = field(default_factory=dict)
    last_id: int | None = None
    goals: int = 0
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False, compare=False)

    def add(self, name: str, n: int = 1) -> None:
        with self._lock:
            setattr(self, name, getattr(self, name) + n)

    def skip(self, reason: str) -> None:
        with self._lock:
            self.skipped[reason] = self.skipped.get(reason, 0) + 1

    def stored_as(self, memory_id: int) -> None:
        with self._lock:
            self.stored += 1
            self.last_id = memory_id

    def as_dict(self) -> dict[str, Any]:
        with self._lock:
            return {
                "images": self.images,
                "poses": self.poses,
                "stored": self.stored,
                "skipped": dict(self.skipped),
                "last_id": self.last_id,
                "goals": self.goals,
            }


@dataclass
class _Waiting:
    t: float
    msg: Any
    msgtype: str
    since: float  # monotonic arrival time


class RosLink:
    """Decode, pair and store, one message at a time; not thread-safe (one caller feeds it).

    `image(key, payload)` and `pose(key, payload)` take a message's CDR bytes as they came off
    the wire; `tick()` settles images that waited long enough; `flush()` settles all (at the
    end). Each settled image goes to the sink or is counted in `stats.skipped`.
    """

    def __init__(
        self,
        cfg: LinkConfig,
        sink: Sink,
        clock: Callable[[], float] = time.time,
        monotonic: Callable[[], float] = time.monotonic,
    ) -> None:
        self.cfg = cfg
        self.sink = sink
        self.clock = clock
        self.monotonic = monotonic
        self.stats = LinkStats()
        self.poses = PoseHistory(cfg)
        self.image_types = MessageTypes(rosmsg.IMAGE_TYPES, cfg.image_type)
        self.pose_types = MessageTypes((*rosmsg.POSE_TYPES, rosmsg.TF), cfg.pose_type)
        self._waiting: deque[_Waiting] = deque()
        self._header = cfg.time == "header"

    # ---------------------------------------------------------------- input
    def image(self, key: str, payload: bytes | memoryview, recv_t: float | None = None) -> None:
        """One image message (Image or CompressedImage CDR)."""
        self.stats.add("images")
        got = self.image_types.decode(key, payload)
        if got is None:
            self.stats.skip(SKIP_TYPE)
            return
        msg, msgtype = got
        t = rosmsg.stamp(msg, self.clock() if recv_t is None else recv_t, self._header)
        self._waiting.append(_Waiting(t, msg, msgtype, self.monotonic()))
        self.tick()

    def pose(self, key: str, payload: bytes | memoryview, recv_t: float | None = None) -> None:
        """One pose message (Odometry, PoseStamped, PoseWithCovarianceStamped or TFMessage CDR)."""
        got = self.pose_types.decode(key, payload)
        if got is None:
            self.stats.skip(f"{SKIP_TYPE} on {key}")
            return
        msg, msgtype = got
        recv = self.clock() if recv_t is None else recv_t
        if msgtype == rosmsg.TF:
            if self.poses.tree is None:
                self.stats.skip(
                    f"tf message on {key} but the pose key carries {self.cfg.pose_type or 'poses'}"
                )
                return
            static = self.cfg.tf_static_key is not None and key == self.cfg.tf_static_key
            for tf in rosmsg.tf_samples(msg, recv, self._header):
                self.poses.add_tf(tf, static)
        else:
            if self.poses.tree is not None:
                self.stats.skip(f"pose message on {key} but the pose key carries tf")
                return
            pq = rosmsg.pose_of(msg, msgtype)
            if pq is None:
                self.stats.skip(f"invalid pose message on {key}")
                return
            self.poses.add(rosmsg.Sample(rosmsg.stamp(msg, recv, self._header), *pq))
        self.stats.add("poses")
        self.tick()

    # ---------------------------------------------------------------- pairing
    def tick(self) -> None:
        """Settle the waiting images whose poses are known, or that waited too long."""
        now = self.monotonic()
        newest = self.poses.newest if self._waiting else None
        while self._waiting:
            w = self._waiting[0]
            ready = newest is not None and newest >= w.t
            expired = now - w.since >= self.cfg.wait or len(self._waiting) > self.cfg.max_pending
            if not (ready or expired):
                break
            self._waiting.popleft()
            self._settle(w, final=not ready)

    def flush(self) -> None:
        """Settle every waiting image with the poses known now (the link is stopping)."""
        while self._waiting:
            w = self._waiting.popleft()
            newest = self.poses.newest
            self._settle(w, final=newest is None or newest < w.t)

    @property
    def waiting(self) -> int:
        return len(self._waiting)

    def _settle(self, w: _Waiting, final: bool) -> None:
        pose = self.poses.lookup(w.t)
        if final and isinstance(pose, str):
            # no later pose came: past the newest pose is not "outside the track", it is late
            newest = self.poses.newest
            pose = SKIP_NO_POSE if newest is None or w.t > newest else pose
        if isinstance(pose, str):
            self.stats.skip(pose)
            return
        image = rosmsg.decode_image(w.msg, w.msgtype)
        if isinstance(image, str):
            self.stats.skip(image)
            return
        try:
            result = self.sink(image, pose, w.t)
        except InputError as e:  # e.g. the writer is busy or closing
            self.stats.skip(str(e).split(":", 1)[0][:80])
            return
        if isinstance(result, str):
            self.stats.skip(result)
        else:
            self.stats.stored_as(int(result))

    # ---------------------------------------------------------------- answers
    def goal_bytes(self, answer: dict[str, Any], t: float | None = None) -> bytes | None:
        """CDR of the goal PoseStamped for an answer with a position, else None."""
        goal = answer_goal(answer)
        if goal is None:
            return None
        x, y, z, yaw = goal
        msg = rosmsg.pose_stamped(x, y, z, yaw, self.clock() if t is None else t, self.cfg.goal_frame)
        return rosmsg.serialize(msg, rosmsg.POSE_STAMPED)


def answer_goal(answer: dict[str, Any]) -> tuple[float, float, float, float | None] | None:
    """(x, y, z, yaw) of an answer (`ravenmem ask --json` shape) that found a position, else None."""
    pos = answer.get("position")
    if answer.get("failed") or not answer.get("found", True) or not isinstance(pos, (list, tuple)):
        return None
    if len(pos) != 3 or not all(isinstance(v, (int, float)) and math.isfinite(v) for v in pos):
        return None
    yaw = answer.get("yaw")
    yaw = float(yaw) if isinstance(yaw, (int, float)) and math.isfinite(yaw) else None
    return float(pos[0]), float(pos[1]), float(pos[2]), yaw


# -------------------------------------------------------------------- Zenoh


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
            raise InputError(f"zenoh config {self.config_file}: {_short(e)}") from None
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
                f"zenoh endpoints {list(self.connect) + list(self.listen)}: {_short(e)}"
            ) from None
        return conf


def _short(e: BaseException) -> str:
    """Zenoh's error text on one line, without the Rust source location it appends."""
    text = " ".join(str(e).split())
    return text.split(" at /", 1)[0][:300]


class ZenohLink:
    """`RosLink` behind Zenoh subscribers: the callbacks only queue the bytes; one worker thread
    decodes, pairs and calls the sink (which may block while a frame is stored), so Zenoh's
    threads never wait on the embedder. At most `max_queued_images` images wait in the queue;
    beyond that the newest is dropped and counted (`SKIP_BUSY`) rather than memory growing."""

    def __init__(
        self,
        cfg: LinkConfig,
        sink: Sink,
        endpoints: ZenohEndpoints | None = None,
        max_queued_images: int = 16,
    ) -> None:
        self.cfg = cfg
        self.link = RosLink(cfg, sink)
        self.endpoints = endpoints or ZenohEndpoints()
        self.max_queued_images = max_queued_images
        self._queue: queue.Queue[tuple[str, str, bytes, float] | None] = queue.Queue(maxsize=10_000)
        self._images_queued = 0
        self._lock = threading.Lock()
        self._session: Any = None
        self._subs: list[Any] = []
        self._goal_pub: Any = None
        self._thread: threading.Thread | None = None

    @property
    def stats(self) -> LinkStats:
        return self.link.stats

    def start(self) -> ZenohLink:
        """Open the session, declare the subscribers (and the goal publisher), start the worker."""
        zenoh: Any = require("zenoh", "robot")
        try:
            self._session = zenoh.open(self.endpoints.config())
        except InputError:
            raise
        except Exception as e:
            raise InputError(f"zenoh: cannot open a session ({_short(e)})") from None
        try:
            for role, key in (("image", self.cfg.image), ("pose", self.cfg.pose)):
                self._subs.append(self._session.declare_subscriber(key, self._callback(role)))
            if self.cfg.tf_static_key:
                self._subs.append(self._latched(self.cfg.tf_static_key, self._callback("pose")))
            if self.cfg.goal:
                self._goal_pub = self._session.declare_publisher(self.cfg.goal)
        except Exception as e:
            self.close()
            raise InputError(f"zenoh: cannot subscribe ({_short(e)})") from None
        self._thread = threading.Thread(target=self._run, name="ravenmem-zenoh", daemon=True)
        self._thread.start()
        return self

    def _latched(self, key: str, callback: Callable[[Any], None]) -> Any:
        """A subscriber that also fetches what was published before it joined (/tf_static is
        "transient local" in ROS 2: sent once, at start-up). Zenoh's advanced subscriber asks
        the caches of advanced publishers (rmw_zenoh's and the bridge's transient-local
        publishers keep one); where that API is missing, a plain subscriber."""
        zenoh: Any = require("zenoh", "robot")
        ext = getattr(zenoh, "ext", None)
        try:
            history = ext.HistoryConfig(detect_late_publishers=True)  # type: ignore[union-attr]
            return ext.declare_advanced_subscriber(self._session, key, callback, history=history)  # type: ignore[union-attr]
        except Exception as e:  # an older zenoh, or one built without the unstable API
            log.warning("zenoh link: no history for %s (%s); start the link before the robot", key, e)
            return self._session.declare_subscriber(key, callback)

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
                log.exception("zenoh link: handling a message on %s failed", key)
        self.link.flush()

    def publish_goal(self, answer: dict[str, Any]) -> bool:
        """Publish the answer's position as a PoseStamped on the goal key; False when there is
        no goal key or the answer has no position."""
        if self._goal_pub is None:
            return False
        payload = self.link.goal_bytes(answer)
        if payload is None:
            return False
        self._goal_pub.put(payload)
        self.link.stats.add("goals")
        return True

    def on_answer(self, answer: dict[str, Any]) -> None:
        """The service's answer hook: an answer with a position becomes a goal (when configured)."""
        self.publish_goal(answer)

    def describe(self) -> dict[str, Any]:
        """What `/info` shows under `links`: the keys and the counts."""
        keys = {"image": self.cfg.image, "pose": self.cfg.pose, "tf_static": self.cfg.tf_static_key}
        out: dict[str, Any] = {"kind": "zenoh", **keys, "goal": self.cfg.goal, "waiting": self.link.waiting}
        if self.cfg.tf:  # which frame the poses are in, or why none could be found yet
            out["tf_parent"], out["tf_note"] = self.link.poses.parent, self.link.poses.tf_note
        return out | self.stats.as_dict()

    def close(self, timeout: float = 30.0) -> None:
        """Stop taking messages, settle what is queued, then close the session."""
        for sub in self._subs:
            with contextlib.suppress(Exception):
                sub.undeclare()
        self._subs = []
        if self._thread is not None:
            self._queue.put(None)
            self._thread.join(timeout)
            self._thread = None
        if self._session is not None:
            with contextlib.suppress(Exception):
                self._session.close()
            self._session = None


def writer_sink(writer: LiveWriter, source: str, timeout: float = 60.0) -> Sink:
    """The service's one writer as a sink: each frame goes through its keyframe rule, embedder
    and store, and the call returns once the frame is durable (or skipped, with the reason)."""

    def sink(image: np.ndarray, pose: Pose, t: float) -> int | str:
        try:
            res = writer.add(image, pose, t, source=source, timeout=timeout)
        except FutureTimeout:
            return SKIP_SLOW
        return res.id if res.id is not None else str(res.skipped)

    return sink


def start_link(service: Service, cfg: LinkConfig, endpoints: ZenohEndpoints | None = None) -> ZenohLink:
    """Start the robot link on a service (`ravenmem serve --zenoh`): frames into its writer,
    answers with a position out as goals; closed with the service."""
    if service.writer is None:
        raise InputError("--zenoh adds frames to the memory: it cannot run with --read-only")
    service.start()
    link = ZenohLink(cfg, writer_sink(service.writer, cfg.source), endpoints).start()
    service.attach(link)
    log.info(
        "zenoh link: images on %s, poses on %s%s",
        cfg.image,
        cfg.pose,
        f", goals on {cfg.goal}" if cfg.goal else "",
    )
    return link
