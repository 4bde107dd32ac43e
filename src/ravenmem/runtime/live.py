"""Live adds: the one writer of a served memory.

A robot streams frames (RGB + pose + time) into a running memory. Every frame goes through the
same admission stage as a recorded ingest (`ingest.admit.Admission`: time check, map, keyframe
prefilter, embedder, novelty rule, `Memory.add_frames`; keyframe state per source, so two
cameras do not thin each other out). What this adds is the queue. `submit` runs the cheap steps
(time check, map, prefilter) in the caller's thread, in arrival order, so a frame they skip is
answered at once instead of waiting behind the embedding of the frames before it; the frames
that pass are queued, and one thread embeds them (those that arrive together in one batch),
applies the novelty rule and stores them, in the same order, so the keyframe state and the store
see one writer; searches run meanwhile on other threads.

A kept frame is answered only after `add_frames` returned, i.e. after the store made it durable:
an acknowledged memory survives a crash of the service. On a memory with OCR its text is read
after that answer (`add_frames(text="later")`, `ravenmem.memory.text`): searchable by picture at
once, by its words when the text lands, and journalled, so a crash loses neither. Every front
end that adds frames (the HTTP route, the Zenoh link) calls `LiveWriter.add` (blocking) or
`LiveWriter.submit` (a future):

    writer = LiveWriter(mem, KeyframeConfig(fps=2))
    writer.start()
    result = writer.add(rgb, Pose(1.0, 2.0, yaw=0.3), t=time.time(), source="front")
    result.id or result.skipped   # the new memory's id, or why the frame was not kept

With a `mapper` (a `ravenmem.nav.mapping.MapBuilder`), every frame that comes with depth is
fused into the memory's occupancy map before the keyframe rule, as a recorded ingest does; the
map is saved every `mapper.save_every` mapped frames and when the writer closes.
"""

from __future__ import annotations

import logging
import math
import numbers
import queue
import threading
import time
from collections.abc import Callable
from concurrent.futures import Future
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ..errors import InputError, RavenmemError
from ..ingest.admit import Admission
from ..ingest.keyframes import KeyframeConfig
from ..memory import Memory
from ..threads import WRITER_NICE, lower_priority
from ..types import Frame, MemoryRecord, Pose

log = logging.getLogger(__name__)


class BusyError(InputError):
    """The writer's queue is full: the client should slow down (HTTP 503)."""


@dataclass(frozen=True)
class AddResult:
    """What became of one frame: stored under `id`, or `skipped` with the keyframe rule's reason."""

    t: float
    source: str
    id: int | None = None
    skipped: str | None = None

    @property
    def stored(self) -> bool:
        return self.id is not None

    def as_json(self) -> dict[str, Any]:
        return {
            "stored": self.stored,
            "id": self.id,
            "skipped": self.skipped,
            "t": self.t,
            "source": self.source,
        }


@dataclass
class LiveStats:
    """Counts since the writer started, per outcome (what `/info` shows under `live`)."""

    seen: int = 0
    kept: int = 0
    skipped: dict[str, int] = field(default_factory=dict)

    def as_dict(self) -> dict[str, Any]:
        return {"frames_seen": self.seen, "kept": self.kept, "skipped": dict(self.skipped)}


@dataclass
class _Job:
    frame: Frame
    future: Future[AddResult]


class _LoggedMap:
    """The map builder as live adds use it: a frame the map cannot take is logged, and the
    frame still goes on to the memory."""

    def __init__(self, mapper: Any) -> None:
        self.mapper = mapper

    def add(self, frame: Frame) -> bool:
        try:
            return bool(self.mapper.add(frame))
        except Exception:
            log.exception("mapping a live frame failed")
            return False

    def close(self) -> None:
        try:
            self.mapper.close()
        except Exception:  # the memory itself is stored; a map that failed to save is logged
            log.exception("saving the live map failed")


class LiveWriter:
    """One thread that keyframes, embeds and stores frames in arrival order.

    `on_result(result, record)` is called from the writer thread after each frame (the record is
    None for a skipped frame); the service uses it to publish events. `max_pending` bounds the
    queue: beyond it `submit` raises `BusyError` instead of letting memory grow. Frames waiting
    together are embedded and stored in one batch of at most `batch` (same result as one by one:
    the keyframe rules still see them in order).
    """

    def __init__(
        self,
        mem: Memory,
        keyframes: KeyframeConfig | None = None,
        on_result: Callable[[AddResult, MemoryRecord | None], None] | None = None,
        max_pending: int = 256,
        batch: int = 16,
        mapper: Any | None = None,
    ) -> None:
        self.mem = mem
        self.mapper = mapper
        self.cfg = keyframes if keyframes is not None else KeyframeConfig()
        self.stage = Admission(
            mem, self.cfg, _LoggedMap(mapper) if mapper is not None else None, number=True, text="later"
        )
        self.on_result = on_result
        self.batch = max(1, batch)
        self.stats = LiveStats()
        self._queue: queue.Queue[_Job | None] = queue.Queue(maxsize=max(1, max_pending))
        self._thread: threading.Thread | None = None
        self._closed = False
        self._lock = threading.Lock()  # submit's: the keyframe state and the queue, in arrival order
        self._stats_lock = threading.Lock()

    # ---------------------------------------------------------------- lifecycle
    def start(self) -> LiveWriter:
        with self._lock:
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="ravenmem-writer", daemon=True)
                self._thread.start()
        return self

    def close(self, timeout: float = 30.0) -> None:
        """Finish the frames already queued, then stop (later submits are refused)."""
        with self._lock:
            if self._closed:
                return
            self._closed = True
            thread = self._thread
        if thread is not None:
            self._queue.put(None)
            thread.join(timeout)
        if self.stage.mapper is not None:
            self.stage.mapper.close()

    # ---------------------------------------------------------------- adding
    def submit(
        self, image: np.ndarray, pose: Pose, t: float, source: str = "live", depth: np.ndarray | None = None
    ) -> Future[AddResult]:
        """Queue one frame (with `depth` in metres, for the map); the future resolves once it
        is stored (or skipped)."""
        frame = _checked_frame(image, pose, t, source)
        if depth is not None:
            if (
                not isinstance(depth, np.ndarray)
                or depth.ndim != 2
                or not np.issubdtype(depth.dtype, np.floating)
            ):
                raise InputError(
                    f"depth must be a 2-D float array in metres, got {getattr(depth, 'shape', None)}"
                )
            frame.depth = depth
        fut: Future[AddResult] = Future()
        with self._lock:
            if self._closed:
                raise InputError("the memory is closing: no more frames are taken")
            if self._thread is None:
                raise InputError("the writer is not started")
            if self._queue.full():  # only submit puts (under this lock): a frame screened is queued
                raise BusyError(f"{self._queue.maxsize} frames are waiting to be stored: slow down")
            # the cheap steps here, in arrival order: a frame they skip is answered at once,
            # without waiting behind the embedding of the frames queued before it
            reason = self.stage.screen(frame, frame.source)
            self.stats.seen += 1
            if reason is None:
                self._queue.put_nowait(_Job(frame, fut))
                return fut
            self._count(reason)
        self._answer(fut, AddResult(t=frame.t, source=frame.source, skipped=reason), None)
        return fut

    def add(
        self,
        image: np.ndarray,
        pose: Pose,
        t: float,
        source: str = "live",
        timeout: float | None = 60.0,
        depth: np.ndarray | None = None,
    ) -> AddResult:
        """Add one frame and wait until it is durable (or skipped); the blocking form of `submit`."""
        return self.submit(image, pose, t, source, depth).result(timeout)

    # ---------------------------------------------------------------- the writer thread
    def _run(self) -> None:
        lower_priority(WRITER_NICE)  # searches first (`ravenmem.threads`)
        stop = False
        while not stop:
            job = self._queue.get()
            if job is None:
                break
            jobs = [job]
            while len(jobs) < self.batch:
                try:
                    nxt = self._queue.get_nowait()
                except queue.Empty:
                    break
                if nxt is None:
                    stop = True
                    break
                jobs.append(nxt)
            self._write(jobs)

    def _write(self, jobs: list[_Job]) -> None:
        try:
            self._store(jobs)
        except Exception as e:  # a failed batch fails its frames, not the writer
            if not isinstance(e, RavenmemError):  # bad input, a full disk: the client is told
                log.exception("storing %d live frame(s) failed", len(jobs))
            for j in jobs:
                if not j.future.done():
                    j.future.set_exception(e)

    def _store(self, jobs: list[_Job]) -> None:
        outcomes = self.stage.admit([(j.frame.source, j.frame) for j in jobs])
        ids = [o for o in outcomes if isinstance(o, int)]
        records = {r.id: r for r in self.mem.get(ids)} if ids else {}
        for j, o in zip(jobs, outcomes):
            if isinstance(o, int):
                self._count(None)
                self._answer(j.future, AddResult(t=j.frame.t, source=j.frame.source, id=o), records[o])
            else:
                self._count(str(o))
                self._answer(j.future, AddResult(t=j.frame.t, source=j.frame.source, skipped=str(o)), None)

    def _count(self, skipped: str | None) -> None:
        with self._stats_lock:
            if skipped is None:
                self.stats.kept += 1
            else:
                self.stats.skipped[skipped] = self.stats.skipped.get(skipped, 0) + 1

    def _answer(self, fut: Future[AddResult], res: AddResult, rec: MemoryRecord | None) -> None:
        self._notify(res, rec)  # before the answer: the events keep the order the answers have
        fut.set_result(res)

    def _notify(self, res: AddResult, rec: MemoryRecord | None) -> None:
        if self.on_result is None:
            return
        try:
            self.on_result(res, rec)
        except Exception:  # a listener's bug must not stop the writer
            log.exception("live result listener failed")

    def report(self) -> dict[str, Any]:
        """The live counts in the shape of an ingest report (appended to the manifest on close)."""
        out = {
            "source": "live",
            "frames_seen": self.stats.seen,
            "kept": self.stats.kept,
            "skipped": dict(self.stats.skipped),
            "ended": time.time(),
        }
        if self.mapper is not None:
            out["map"] = {
                "frames_mapped": self.mapper.stats.mapped,
                "skipped": dict(self.mapper.stats.skipped),
            }
        return out


def _checked_frame(image: np.ndarray, pose: Pose, t: float, source: str) -> Frame:
    """A frame the store will take, or a one-line `InputError` naming what is wrong."""
    if not isinstance(image, np.ndarray) or image.ndim != 3 or image.shape[2] != 3 or image.dtype != np.uint8:
        raise InputError(f"image must be an RGB uint8 array (H, W, 3), got {getattr(image, 'shape', None)}")
    if not isinstance(pose, Pose):
        raise InputError("pose must be a ravenmem.Pose")
    if isinstance(t, bool) or not isinstance(t, numbers.Real) or not math.isfinite(t):
        raise InputError(f"t must be a finite number of Unix seconds, got {t!r}")
    if not source or len(source) > 200 or not source.isprintable():
        raise InputError("source must be a printable name of 1 to 200 characters")
    frame = Frame(image=image, t=float(t), pose=pose, source=source, index=0)
    frame.check()  # what a memory stores (ravenmem.types): refused here, not in the writer's batch
    return frame
