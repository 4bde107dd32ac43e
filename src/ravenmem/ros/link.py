"""The robot link's logic, with no transport in it: a ROS 2 camera and pose stream into a live
memory, and goals back out, fed message by message (the Zenoh link and the ROS 2 node carry
the bytes; the tests feed it directly).

ROS 2 robots reach other processes over Zenoh: `zenoh-bridge-ros2dds` publishes each topic's CDR
bytes on a key named after the topic (`/camera/color/image_raw` on `camera/color/image_raw`), and
`rmw_zenoh` publishes on `<domain>/<topic>/<type>/<hash>` keys. The link takes one image key and
one pose key (nav_msgs/Odometry, geometry_msgs/PoseStamped or PoseWithCovarianceStamped, or /tf
plus /tf_static), decodes the CDR with `rosbags` through the same converters as the bag source
(`ros.msgs`), poses each image at its stamp from the recent poses (interpolated, or the nearest
within a gap: a pose topic as `ingest.poses.PoseTrack` does for bags, TF through the bounded
`ros.tf.TfBuffer` of the rclpy node) and hands (RGB, pose, time) to a sink:
the service's one writer, which runs the online keyframe rule and stores. Every frame that does
not become a memory is counted with its reason.

An image newer than the newest pose waits (at most `wait` seconds, at most `max_pending`
images) for the poses that bracket it; odometry usually lags the camera a little. Nothing is
guessed: an image whose pose never comes is counted as `SKIP_NO_POSE`.

Frames: the poses' frame (REP 105) is the TF parent, or the pose messages' `header.frame_id`.
It is checked once against the memory's (`frame_check`): poses of another frame are not stored.
Goals are the answers' `nav.goals` plans, published as the plan's own PoseStamped, which is in
the memory's frame: nothing here chooses a goal frame.

The pose options are named as the bag source's: `tf_parent`, `tf_child`, `time_source`,
`pose_match`, `max_gap`. `LinkConfig.from_spec` reads the `serve --zenoh` string into the typed
config, whose fields are the keys.
"""

from __future__ import annotations

import bisect
import logging
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import TimeoutError as FutureTimeout
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from ..errors import InputError
from ..ingest.poses import PoseTrack, check_match_mode
from ..spec import pairs
from ..stamps import sec_nanosec
from ..types import Pose
from . import msgs
from .tf import MAX_GAP, REFUSED, TIME_SOURCES, TOO_NEW, TfBuffer, check_time_source, norm_frame

if TYPE_CHECKING:
    from ..agent.ask import PlanLike
    from ..runtime.live import LiveWriter

log = logging.getLogger(__name__)

SKIP_NO_POSE = "no pose in time"  # the pose stream is late, stopped or never started
SKIP_BUSY = "link busy: frame dropped before storing"
SKIP_TYPE = "undecodable message"  # not CDR of any type this key may carry
SKIP_SLOW = "not stored in time"  # the writer did not answer within its timeout

# What a sink does with a posed frame: the new memory's id, or the reason it was not kept.
Sink = Callable[[np.ndarray, Pose, float], "int | str"]
# The poses' frame, once known, checked against the memory's: None when fine, else the reason.
FrameCheck = Callable[[str], "str | None"]


class LinkConfig(BaseModel):
    """What to subscribe to, how to pair images with poses, and what to serve.

    image / pose: Zenoh key expressions of the image topic and of the pose topic (or /tf).
    image_type / pose_type: the ROS type when the key does not say (None: the type an rmw_zenoh
    key names, else the first candidate type the first message decodes as, then kept).
    tf_static: key of /tf_static (default `tf_static` when the pose key carries TF).
    tf_parent / tf_child: TF frames; tf_parent None picks map, odom or world, the first that is
    an ancestor of tf_child. pose_match / max_gap: as the bag source (interpolate, or nearest
    within max_gap s; 0.05 s by default with nearest; with TF, interpolation across at most 1 s
    by default, as the node). time_source: `header` (header.stamp, receive time when zero) or
    `receive`. wait: seconds an image waits for a later pose; max_pending: images that may wait
    at once; history: seconds of poses kept (per TF frame). goal: key of the
    goal PoseStamped published after an answer with a plan (in the memory's frame). source: the
    memories' source name. services: the name under which `ravenmem_msgs/srv/Ask` and `Search`
    are served (`/ravenmem/ask`, `/ravenmem/search`; empty: none); domain: the ROS domain id of
    rmw_zenoh keys. action: a NavigateToPose action to drive to each goal (e.g. navigate_to_pose;
    None: only the goal topic).
    """

    model_config = ConfigDict(frozen=True, extra="forbid")

    image: str
    pose: str
    image_type: str | None = None
    pose_type: str | None = None
    tf_static: str | None = None
    tf_parent: str | None = None
    tf_child: str = "base_link"
    pose_match: str = Field("interpolate", description="interpolate | nearest")
    max_gap: float | None = Field(None, ge=0, allow_inf_nan=False)
    time_source: str = Field("header", description=" | ".join(TIME_SOURCES))
    wait: float = Field(1.0, ge=0, allow_inf_nan=False)
    max_pending: int = Field(64, ge=1)
    history: float = Field(30.0, ge=0, allow_inf_nan=False)
    goal: str | None = None
    source: str = "zenoh"
    services: str | None = "ravenmem"
    domain: int = Field(0, ge=0, le=232)
    action: str | None = None

    @field_validator("image", "pose", "tf_static", "goal", "action")
    @classmethod
    def _key(cls, v: str | None, info: Any) -> str | None:
        return None if v is None else check_key(v, info.field_name)

    @field_validator("services")
    @classmethod
    def _services(cls, v: str | None) -> str | None:
        return check_key(v, "services") if v else None

    @field_validator("image_type", "pose_type")
    @classmethod
    def _type(cls, v: str | None, info: Any) -> str | None:
        if v is None:
            return None
        allowed = msgs.IMAGE_TYPES if info.field_name == "image_type" else (*msgs.POSE_TYPES, msgs.TF)
        full = msgs.type_name(v)
        if full not in allowed:
            raise ValueError(f"not one of {', '.join(t.rsplit('/', 1)[1] for t in allowed)}")
        return full

    @field_validator("pose_match")
    @classmethod
    def _match(cls, v: str) -> str:
        return check_match_mode(v)

    @field_validator("time_source")
    @classmethod
    def _time(cls, v: str) -> str:
        return check_time_source(v, "zenoh")

    @field_validator("tf_child", "source")
    @classmethod
    def _name(cls, v: str, info: Any) -> str:
        if not v.strip():
            raise ValueError("must not be empty")
        return v

    @model_validator(mode="after")
    def _nearest_gap(self) -> LinkConfig:
        if self.pose_match == "nearest" and self.max_gap is None:
            object.__setattr__(self, "max_gap", 0.05)
        return self

    @classmethod
    def from_spec(cls, spec: str, **overrides: Any) -> LinkConfig:
        """`image=camera/color/image_raw,pose=odom[,key=value...]` (keys: the fields) -> config;
        a one-line `InputError` naming the key for anything wrong."""
        known = list(cls.model_fields)
        values: dict[str, Any] = dict(pairs(spec, "zenoh", known=known))
        values.update({k: v for k, v in overrides.items() if v is not None})
        for need in ("image", "pose"):
            if need not in values:
                raise InputError(
                    f"zenoh: {need}=KEY is missing (e.g. image=camera/color/image_raw,pose=odom)"
                )
        try:
            return cls(**values)
        except ValidationError as e:
            err = e.errors()[0]
            key = ".".join(str(p) for p in err["loc"]) or "spec"
            msg = str(err["msg"]).removeprefix("Value error, ")
            got = values.get(key)
            if msg.startswith("zenoh: ") or got is None:  # the check named the key itself
                raise InputError(msg if msg.startswith("zenoh: ") else f"zenoh: {msg}") from None
            raise InputError(f"zenoh: {key}={got!r}: {msg}") from None
        except InputError as e:
            raise InputError(str(e)) from None

    @property
    def tf(self) -> bool:
        """Whether poses come from the TF tree (said by pose_type, or by a key named tf)."""
        if self.pose_type is not None:
            return self.pose_type == msgs.TF
        return self.pose.rsplit("/", 1)[-1] == "tf" or msgs.type_from_key(self.pose) == msgs.TF

    @property
    def tf_static_key(self) -> str | None:
        return self.tf_static if self.tf_static is not None else ("tf_static" if self.tf else None)


def check_key(key: str, what: str) -> str:
    """A Zenoh key expression from a ROS topic name or key (the leading '/' of a topic dropped)."""
    k = str(key).strip().strip("/")
    if not k or "//" in k or any(c in k for c in " \t\n#?$,"):
        raise InputError(f"zenoh: {what}={key!r} is not a Zenoh key expression (e.g. camera/color/image_raw)")
    return k


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
        fixed = self.given or msgs.type_from_key(key)
        if fixed is not None:
            if fixed not in self.candidates:
                return None
            try:
                return msgs.deserialize(payload, fixed), fixed
            except Exception:  # rosbags raises SerdeError and friends for bytes of another type
                return None
        last = self.known.get(key)
        for t in ([last] if last else []) + [c for c in self.candidates if c != last]:
            try:
                msg = msgs.deserialize(payload, t)
            except Exception:
                continue
            if t != last and (last is not None or len(self.known) < 1024):
                self.known[key] = t
            return msg, t
        return None


class PoseHistory:
    """The robot's recent poses, from a pose topic or the TF tree, looked up at an image's stamp.
    `frame` is the frame they are in, once known (the TF parent, or the messages' frame_id).

    A pose topic's samples are kept for `history` seconds; a lookup matches (as the bag source's
    `PoseTrack` does) on a track of the few samples around the stamp, so that neither a message
    nor a lookup rebuilds the whole history (per odometry message at 100 Hz with 30 s of
    history and an image waiting: 1.9 ms before, 0.11 ms now; `bench_zenoh_link.py --odom`).
    TF goes into the same
    bounded `tf.TfBuffer` the rclpy node uses (`history` seconds, `max_gap`, or the node's 1 s
    when unset), so both resolve a pose alike: each moving transform interpolated at the stamp,
    refused as `tf.TOO_OLD` or `tf.GAP` in the node's words, and an image newer than the newest
    pose counted `SKIP_NO_POSE`; a message costs O(1) to add and a lookup O(log n) however long
    the link runs (no track is rebuilt). Thread-safe: the link's worker feeds it while the
    services ask for `latest_xy` (one lock, held for microseconds)."""

    def __init__(self, cfg: LinkConfig) -> None:
        self.cfg = cfg
        self._t: list[float] = []
        self._xyz: list[tuple[float, float, float]] = []
        self._quat: list[tuple[float, float, float, float]] = []
        gap = MAX_GAP if cfg.max_gap is None else cfg.max_gap
        self.tf: TfBuffer | None = TfBuffer(cfg.history, max_gap=gap) if cfg.tf else None
        self.tf_note = ""
        self.child = norm_frame(cfg.tf_child)
        self.parent = norm_frame(cfg.tf_parent) if cfg.tf_parent else None
        self.frame: str | None = None
        self._lock = threading.RLock()

    def add(self, sample: msgs.Sample, frame: str = "") -> None:
        with self._lock:
            self._add(sample, frame)

    def _add(self, sample: msgs.Sample, frame: str) -> None:
        if self.frame is None:
            self.frame = norm_frame(frame) or "map"
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

    def add_tf(self, tf: msgs.TfSample, static: bool) -> bool:
        """One transform into the buffer; False when refused (`tf.REFUSED`)."""
        assert self.tf is not None
        with self._lock:
            return self.tf.add(tf.parent, tf.child, tf.t, tf.xyz, tf.quat, static)

    def _near(self, t: float) -> PoseTrack | None:
        """The pose topic's samples next to `t` as a track, or None before the first: matching
        at t (interpolating, or the nearest sample within the gap) reads only the two samples
        that bracket it, and tells "outside" from "gap" by whether t is past the first or
        last sample, which the window then holds."""
        if not self._t:
            return None
        i = bisect.bisect_left(self._t, t)
        lo, hi = max(0, i - 2), min(len(self._t), i + 2)
        return PoseTrack(self._t[lo:hi], self._xyz[lo:hi], self._quat[lo:hi], name=self.cfg.pose)

    def _tf_parent(self) -> str | None:
        """The TF parent: the given one, else the first of map, odom, world that /tf links to
        the child, chosen once (every memory of a run is in the same frame)."""
        assert self.tf is not None
        if self.parent is None:
            self.parent = self.tf.default_parent(self.child)
            if self.parent is None:
                self.tf_note = f"no map/odom/world ancestor of {self.child!r} in tf yet"
                return None
            log.info("robot link: poses of %s in %s (from tf)", self.child, self.parent)
        self.frame = self.parent
        return self.parent

    @property
    def newest(self) -> float | None:
        with self._lock:
            return self._newest()

    def _newest(self) -> float | None:
        if self.tf is None:
            return self._t[-1] if self._t else None
        parent = self._tf_parent()
        if parent is None:
            return None
        t = self.tf.newest(parent, self.child)
        if t is not None:
            self.tf_note = ""
        elif self.tf.chain(parent, self.child) is None:
            self.tf_note = f"no transform from {parent!r} to {self.child!r} in tf yet"
        else:
            self.tf_note = f"{parent} -> {self.child} only has static transforms in tf so far"
        return t

    def latest_xy(self) -> tuple[float, float] | None:
        """Where the robot was at the newest pose (x, y in its frame), or None."""
        with self._lock:
            t = self._newest()
            p = None if t is None else self._lookup(t)
        return None if p is None or isinstance(p, str) else (p.x, p.y)

    def lookup(self, t: float) -> Pose | str:
        """The pose at t, or why there is none: with a pose topic `SKIP_OUTSIDE`, `SKIP_GAP`; with
        TF the node's reasons (`tf.TOO_OLD`, `tf.GAP`, no transform); `SKIP_NO_POSE` for none yet,
        or none as new as t."""
        with self._lock:
            return self._lookup(t)

    def _lookup(self, t: float) -> Pose | str:
        nearest = self.cfg.pose_match == "nearest"
        if self.tf is None:
            tr = self._near(t)
            mode = check_match_mode(self.cfg.pose_match)
            return SKIP_NO_POSE if tr is None else tr.match(t, mode, self.cfg.max_gap)
        parent = self._tf_parent()
        if parent is None:
            return SKIP_NO_POSE
        got = self.tf.lookup(parent, self.child, t, nearest)
        if isinstance(got, str):
            return SKIP_NO_POSE if got == TOO_NEW else got  # as the node's intake
        (x, y, z), q = got
        return Pose.from_quaternion(x, y, z, *q)


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
    questions: int = 0
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
                "questions": self.questions,
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
        frame_check: FrameCheck | None = None,
    ) -> None:
        self.cfg = cfg
        self.sink = sink
        self.clock = clock
        self.monotonic = monotonic
        self.frame_check = frame_check
        self.stats = LinkStats()
        self.poses = PoseHistory(cfg)
        self.image_types = MessageTypes(msgs.IMAGE_TYPES, cfg.image_type)
        self.pose_types = MessageTypes((*msgs.POSE_TYPES, msgs.TF), cfg.pose_type)
        self._waiting: deque[_Waiting] = deque()
        self._header = cfg.time_source == "header"
        self._frame_refusal: str | None = None
        self._frame_checked: str | None = None

    # ---------------------------------------------------------------- input
    def image(self, key: str, payload: bytes | memoryview, recv_t: float | None = None) -> None:
        """One image message (Image or CompressedImage CDR)."""
        self.stats.add("images")
        got = self.image_types.decode(key, payload)
        if got is None:
            self.stats.skip(SKIP_TYPE)
            return
        msg, msgtype = got
        t = msgs.stamp(msg, self.clock() if recv_t is None else recv_t, self._header)
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
        if msgtype == msgs.TF:
            if self.poses.tf is None:
                self.stats.skip(
                    f"tf message on {key} but the pose key carries {self.cfg.pose_type or 'poses'}"
                )
                return
            static = self.cfg.tf_static_key is not None and key == self.cfg.tf_static_key
            for tf in msgs.tf_samples(msg, recv, self._header):
                if not self.poses.add_tf(tf, static):
                    self.stats.skip(REFUSED)
        else:
            if self.poses.tf is not None:
                self.stats.skip(f"pose message on {key} but the pose key carries tf")
                return
            pq = msgs.pose_of(msg, msgtype)
            if pq is None:
                self.stats.skip(f"invalid pose message on {key}")
                return
            frame = str(getattr(getattr(msg, "header", None), "frame_id", "") or "")
            self.poses.add(msgs.Sample(msgs.stamp(msg, recv, self._header), *pq), frame)
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

    def _frame_ok(self) -> str | None:
        """Why the poses' frame may not be stored in the memory (None: it may), checked once."""
        frame = self.poses.frame
        if frame is None or self.frame_check is None:
            return None
        if frame != self._frame_checked:
            self._frame_checked, self._frame_refusal = frame, self.frame_check(frame)
        return self._frame_refusal

    def _settle(self, w: _Waiting, final: bool) -> None:
        pose = self.poses.lookup(w.t)
        if final and isinstance(pose, str):
            # no later pose came: past the newest pose is not "outside the track", it is late
            newest = self.poses.newest
            pose = SKIP_NO_POSE if newest is None or w.t > newest else pose
        if isinstance(pose, str):
            self.stats.skip(pose)
            return
        refused = self._frame_ok()
        if refused is not None:
            self.stats.skip(refused)
            return
        image = msgs.decode_image(w.msg, w.msgtype)
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


def goal_of(plan: PlanLike | None) -> dict[str, Any] | None:
    """The goal PoseStamped (JSON) of a plan (`nav.goals.GoalPlan`) that found a path; None for
    no plan, or one that found none."""
    if plan is None or not plan.ok:
        return None
    return plan.pose_stamped()


def goal_bytes(pose_stamped: dict[str, Any], stamp: float | None = None) -> bytes:
    """CDR of a goal PoseStamped (`nav.goals.pose_stamped` JSON), stamped `stamp` when given."""
    data = dict(pose_stamped)
    if stamp is not None:
        data["header"] = dict(data["header"], stamp=sec_nanosec(stamp))
    return msgs.serialize(msgs.to_message(data, msgs.POSE_STAMPED), msgs.POSE_STAMPED)


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
