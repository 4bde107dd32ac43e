"""Frames from a live ROS 2 graph into the memory's one admission stage, without waiting.

The node's callbacks hand every message here and return: an image waits (in a bounded queue)
for the poses that bracket its stamp, then is posed, decoded and submitted to the runtime's
`LiveWriter` (`submit`: its cheap checks run here, the embedding and the store on its thread);
poses come from odometry or from /tf through the bounded buffers of `ros.tf`. Every image
received is accounted for: stored, skipped with its reason, waiting here, or in the writer's
queue (`Counts.balance` checks it). Bad messages (an image that does not decode, a pose with
NaN or a zero quaternion) are counted by reason and never stored.

Thread-safe: `image`, `odometry`, `transforms`, `settle` and `latest_xy` take one lock (each
is quick: nothing under it waits on the embedder or the disk), so the node runs the image
callbacks in a callback group of their own, never queued behind the pose callbacks, and its
services read the latest pose meanwhile; the writer's answers come from its thread through
`Counts`.
"""

from __future__ import annotations

import math
import threading
import time
from collections import deque
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass, field
from functools import wraps
from typing import TYPE_CHECKING, Any, TypeVar

import numpy as np

from ..errors import InputError
from ..types import Pose
from . import msgs
from .tf import REFUSED, TOO_NEW, PoseBuffer, TfBuffer, norm_frame

if TYPE_CHECKING:
    from ..runtime.live import AddResult, LiveWriter

SKIP_NO_POSE = "no pose in time"
SKIP_QUEUE = "image queue full"
SKIP_WRITER = "writer queue full"
SKIP_STOPPING = "node stopping"
BAD_POSE = "invalid pose (NaN or zero quaternion)"
RGB = "rgb"  # a raw image already decoded


@dataclass
class Counts:
    """What became of every image (thread-safe: the writer thread answers too)."""

    received: int = 0
    stored: int = 0
    skipped: dict[str, int] = field(default_factory=dict)
    bad: dict[str, int] = field(default_factory=dict)  # bad messages of any kind, by reason
    poses: int = 0
    lost: int = 0  # images a publisher sent that never reached the node (`SequenceGaps`)
    dds_lost: int = 0  # images the middleware reported lost (its own count; may overlap `lost`)
    in_writer: int = 0
    last_frame: float | None = None  # monotonic time of the last image
    last_id: int | None = None
    _lock: threading.Lock = field(default_factory=threading.Lock, repr=False)

    def skip(self, reason: str) -> None:
        with self._lock:
            self.skipped[reason] = self.skipped.get(reason, 0) + 1

    def missed(self, n: int, reported: bool = False) -> None:
        """`n` images that never reached the node: found by a sequence gap, or `reported` by
        the middleware."""
        with self._lock:
            if reported:
                self.dds_lost += n
            else:
                self.lost += n

    def bad_message(self, reason: str) -> None:
        with self._lock:
            self.bad[reason] = self.bad.get(reason, 0) + 1

    def submitted(self) -> None:
        with self._lock:
            self.in_writer += 1

    def answered(self, memory_id: int | None, reason: str | None) -> None:
        with self._lock:
            self.in_writer -= 1
            if memory_id is not None:
                self.stored += 1
                self.last_id = memory_id
            else:
                key = reason or "not stored"
                self.skipped[key] = self.skipped.get(key, 0) + 1

    def as_dict(self, pending: int = 0) -> dict[str, Any]:
        with self._lock:
            age = None if self.last_frame is None else time.monotonic() - self.last_frame
            return {
                "received": self.received,
                "stored": self.stored,
                "skipped": dict(self.skipped),
                "pending": pending,
                "in_writer": self.in_writer,
                "lost_in_transport": self.lost,
                "lost_reported_by_dds": self.dds_lost,
                "bad_messages": dict(self.bad),
                "poses": self.poses,
                "last_frame_age": age,
                "last_id": self.last_id,
            }

    def balance(self, pending: int) -> int:
        """received - (stored + skipped + waiting): 0 when every frame is accounted for."""
        with self._lock:
            return self.received - self.stored - sum(self.skipped.values()) - pending - self.in_writer


class SequenceGaps:
    """Images a publisher sent that never reached the node, from the gaps in its publication
    sequence numbers (ROS 2 message info; Fast DDS, Cyclone DDS and rmw_zenoh give them). A
    subscription whose history overflowed while the node was busy drops its oldest images
    without a word (a KEEP_LAST history replaces them; DDS reports no loss), so the gap is the
    only trace; counted, a lost image is never silent. Only gaps after the first image seen from
    a publisher count (what it sent before the node joined was not the node's to get)."""

    MAX_PUBLISHERS = 1024  # publishers remembered (the oldest forgotten past it)

    def __init__(self) -> None:
        self.last: dict[Any, int] = {}

    def missed(self, publisher: Any, seq: int | None) -> int:
        """Images missed before this one (`seq`) from `publisher`; 0 without a number."""
        if not seq or publisher is None:
            return 0
        prev = self.last.pop(publisher, None)
        self.last[publisher] = seq if prev is None else max(seq, prev)  # the newest last
        while len(self.last) > self.MAX_PUBLISHERS:
            del self.last[next(iter(self.last))]
        return 0 if prev is None or seq <= prev else seq - prev - 1


@dataclass
class _Waiting:
    t: float
    msg: Any
    kind: str  # RGB (msg is the array) or msgs.COMPRESSED
    since: float
    source: str


Transform = tuple[tuple[float, float, float], tuple[float, float, float, float]]
F = TypeVar("F", bound=Callable[..., Any])


def _locked(fn: F) -> F:
    """Run a `FrameIntake` method under the intake's lock."""

    @wraps(fn)
    def run(self: FrameIntake, *args: Any, **kwargs: Any) -> Any:
        with self._lock:
            return fn(self, *args, **kwargs)

    return run  # type: ignore[return-value]


class FrameIntake:
    """See the module docstring. `frame_check(frame)` says whether poses in that frame may be
    stored (the service's: the memory's frame is claimed by the first); `log(reason)` is told
    each bad message and skip (the node rate-limits it)."""

    def __init__(
        self,
        writer: LiveWriter,
        settings: Any,
        frame_check: Callable[[str], str | None] | None = None,
        log: Callable[[str], None] = lambda s: None,
    ) -> None:
        self.writer = writer
        self.s = settings
        self.frame_check = frame_check
        self.log = log
        self.counts = Counts()
        self.waiting: deque[_Waiting] = deque()
        self.tf: TfBuffer | None = (
            None if settings.odom_topic else TfBuffer(settings.history, max_gap=settings.max_gap)
        )
        self.odom = PoseBuffer(settings.history, max_gap=settings.max_gap)
        self.frame: str | None = None  # the poses' frame, once known
        self._refused: dict[str, str | None] = {}
        self.gaps = SequenceGaps()
        self.stopping = False
        self.stop_reason = SKIP_STOPPING  # why images are not taken while `stopping`
        self._lock = threading.RLock()

    # ---------------------------------------------------------------- input
    @_locked
    def image(
        self,
        msg: Any,
        kind: str,
        now: float,
        source: str | None = None,
        publisher: Any = None,
        seq: int | None = None,
    ) -> None:
        """One Image or CompressedImage; `now` is the receive time (ROS clock) for a zero stamp;
        `source` the camera's source name (default: `settings.source`); `publisher` and `seq`
        (its publication sequence number, when the middleware gives one) reveal the images
        that never arrived."""
        c = self.counts
        missed = self.gaps.missed(publisher, seq)
        if missed:
            c.missed(missed)
            self.log(f"{missed} image(s) lost before the node took them (sequence gap)")
        with c._lock:
            c.received += 1
            c.last_frame = time.monotonic()
        if self.stopping:
            self._skip(self.stop_reason)
            return
        t = msgs.stamp(msg, now)
        if kind == msgs.IMAGE:  # checked (encoding, size, data) and copied out now: cheap
            rgb = msgs.decode_image(msg, kind)
            if isinstance(rgb, str):
                self._bad(rgb)
                self._skip(rgb)
                return
            msg, kind = rgb, RGB
        self.waiting.append(_Waiting(t, msg, kind, time.monotonic(), source or self.s.source))
        while len(self.waiting) > self.s.queue_size:
            self.waiting.popleft()
            self._skip(SKIP_QUEUE)
        self.settle()

    @_locked
    def odometry(self, msg: Any, now: float) -> None:
        pq = msgs.pose_of(msg, msgs.ODOMETRY)
        if pq is None:
            self._bad(BAD_POSE)
            return
        frame = norm_frame(str(msg.header.frame_id or "")) or self.s.odom_frame
        if self.frame is None:
            self.frame = frame
        elif frame != self.frame:
            self._bad(f"odometry in frame {frame!r}, not {self.frame!r}")
            return
        self.odom.add(msgs.stamp(msg, now), *pq)
        self.counts.poses += 1
        self.settle()

    @_locked
    def transforms(self, msg: Any, now: float, static: bool) -> None:
        assert self.tf is not None
        for tfm in msg.transforms:
            tr, rot = tfm.transform.translation, tfm.transform.rotation
            xyz = (float(tr.x), float(tr.y), float(tr.z))
            q = (float(rot.x), float(rot.y), float(rot.z), float(rot.w))
            n = math.sqrt(sum(v * v for v in q))
            if not all(math.isfinite(v) for v in (*xyz, *q)) or n < 1e-9:
                self._bad(BAD_POSE)
                continue
            q = (q[0] / n, q[1] / n, q[2] / n, q[3] / n)
            t = msgs.stamp(tfm, now)
            if not self.tf.add(tfm.header.frame_id, tfm.child_frame_id, t, xyz, q, static):
                self._bad(REFUSED)
        self.counts.poses += 1
        self.settle()

    # ---------------------------------------------------------------- poses
    def _parent(self) -> str | None:
        """The frame poses are in: the map frame when /tf links it to the base, else odom."""
        if self.frame is not None or self.tf is None:
            return self.frame
        return self.tf.default_parent(self.s.base_frame, (self.s.map_frame, self.s.odom_frame))

    def newest(self) -> float | None:
        if self.tf is None:
            return self.odom.newest
        parent = self._parent()
        return None if parent is None else self.tf.newest(parent, self.s.base_frame)

    def pose_at(self, t: float) -> tuple[str, Transform] | str:
        if self.tf is None:
            got = self.odom.at(t)
            return got if isinstance(got, str) else (self.frame or self.s.odom_frame, got)
        parent = self._parent()
        if parent is None:
            return SKIP_NO_POSE
        got = self.tf.lookup(parent, self.s.base_frame, t)
        return got if isinstance(got, str) else (parent, got)

    @_locked
    def latest_xy(self) -> tuple[float, float] | None:
        t = self.newest()
        got = None if t is None else self.pose_at(t)
        return None if got is None or isinstance(got, str) else (got[1][0][0], got[1][0][1])

    # ---------------------------------------------------------------- settling
    @_locked
    def settle(self, flush: bool = False) -> None:
        """Pose and submit every waiting image whose poses are known, or that waited too long
        (`flush`: all of them, the node is stopping)."""
        now = time.monotonic()
        newest = self.newest() if self.waiting else None
        while self.waiting:
            w = self.waiting[0]
            ready = newest is not None and newest >= w.t
            if not (ready or flush or now - w.since >= self.s.pose_wait):
                break
            self.waiting.popleft()
            self._submit(w)

    def _submit(self, w: _Waiting) -> None:
        got = self.pose_at(w.t)
        if isinstance(got, str):
            self._skip(SKIP_NO_POSE if got == TOO_NEW else got)
            return
        frame, (xyz, q) = got
        refused = self._frame_refusal(frame)
        if refused is not None:
            self._skip(refused)
            return
        image = w.msg if w.kind == RGB else msgs.decode_image(w.msg, w.kind)
        if isinstance(image, str):
            self._bad(image)
            self._skip(image)
            return
        if self.counts.in_writer >= self.s.writer_depth:  # the embedder is behind: fresh frames
            self._skip(SKIP_WRITER)  # beat a backlog stored minutes late
            return
        try:
            pose = Pose.from_quaternion(*xyz, *q)
            fut = self.writer.submit(image, pose, w.t, source=w.source)
        except InputError as e:  # BusyError (the writer's queue is full), a closing memory
            self._skip(SKIP_WRITER if type(e).__name__ == "BusyError" else str(e).split(":", 1)[0][:80])
            return
        self.counts.submitted()
        fut.add_done_callback(self._answered)

    def _answered(self, fut: Future[AddResult]) -> None:
        try:
            res = fut.result()
        except Exception as e:  # the batch failed (a full disk): counted with its reason
            self.counts.answered(None, f"store failed: {str(e)[:60]}")
            return
        self.counts.answered(res.id, None if res.id is not None else str(res.skipped))

    def _frame_refusal(self, frame: str) -> str | None:
        if self.frame_check is None:
            return None
        if frame not in self._refused:
            self._refused[frame] = self.frame_check(frame)
            if self._refused[frame] is None:
                self.frame = frame  # chosen once: every memory of a run is in the same frame
        return self._refused[frame]

    def _skip(self, reason: str) -> None:
        self.counts.skip(reason)
        self.log(reason)

    def _bad(self, reason: str) -> None:
        self.counts.bad_message(reason)
        self.log(reason)

    def camera_info_ok(self, msg: Any) -> str | None:
        """Why a CameraInfo cannot be kept (None: it can)."""
        k = np.asarray(msg.k, dtype=np.float64)
        if k.size != 9 or not np.all(np.isfinite(k)) or k[0] <= 0 or k[4] <= 0:
            return "camera info without K"
        if int(msg.width) <= 0 or int(msg.height) <= 0:
            return "camera info without a size"
        return None
