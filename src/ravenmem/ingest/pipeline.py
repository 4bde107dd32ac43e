"""source -> keyframes -> embedder -> store, in batches, each batch durable when written.

Cheap selection (stride, rate, pose motion) runs before the embedder; novelty by embedding
runs after it, on vectors that are then stored as they are (no frame is embedded twice).

Re-running an ingest resumes it: a frame the memory already holds from the same recording
(same source identity, see `ingest.identity`, and same frame index or timestamp) is skipped and
counted as `already in memory`. Every frame still goes through the keyframe rules in order, and
the novelty rule is replayed on the stored embeddings of the skipped frames before the next new
frame, so a run killed at any point and started again keeps the frames one run would have kept.
Frames that carry depth also feed an optional `mapper` (every one, not only keyframes). Each
frame goes through the admission stage that live adds use too (`ingest.admit`); on a memory with
OCR the keyframes' text is read in a thread while the next frames are embedded.
"""

from __future__ import annotations

import sys
import time
from collections import deque
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from tqdm import tqdm

from ..errors import InputError
from ..types import Frame, MemoryRecord
from .admit import SKIP_NO_POSE, SKIP_TIME, Admission, Replay
from .base import FrameSink, FrameSource
from .identity import source_identity
from .keyframes import KeyframeConfig

if TYPE_CHECKING:
    from ..memory import Memory
    from ..store.base import Store

ALREADY = "already in memory"
PREFILTER = "keyframe selection (stride/rate/motion)"
REPLAY = 64  # stored frames replayed through the novelty rule before the next new one


@dataclass
class IngestReport:
    """What one ingest run saw, kept and dropped (with reasons)."""

    source: str
    source_id: str = ""
    frames_seen: int = 0
    frames_decoded: int = 0
    candidates: int = 0
    kept: int = 0
    skipped: dict[str, int] = field(default_factory=dict)
    raw_bytes: int = 0
    seconds: float = 0.0
    first_id: int | None = None
    last_id: int | None = None
    warnings: list[str] = field(default_factory=list)

    @property
    def keyframes_per_s(self) -> float:
        return self.kept / self.seconds if self.seconds > 0 else 0.0

    @property
    def keyframe_ratio(self) -> float | None:
        """Frames seen per frame kept (None when nothing was kept)."""
        return self.frames_seen / self.kept if self.kept else None

    def as_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["keyframes_per_s"] = round(self.keyframes_per_s, 3)
        d["keyframe_ratio"] = None if self.keyframe_ratio is None else round(self.keyframe_ratio, 3)
        return d


def _emb(r: MemoryRecord) -> np.ndarray:
    assert r.embedding is not None
    return r.embedding


class StoredFrames:
    """The frames of one recording the memory already holds, for O(log n) membership tests.

    Looked up under the source identity (a match on frame index or on timestamp) and, for
    memories written before identities existed, under the path string frames then carried
    (`Frame.source` as the source yields it, and its resolved form; a match needs both frame
    index and timestamp there, since a path may now hold another recording).
    """

    def __init__(self, store: Store, identity: str) -> None:
        self.store = store
        self.identity = identity
        sf = store.source_frames(identity)
        self._idx, self._idx_ids = sf.frame_index, sf.ids
        order = np.argsort(sf.t, kind="stable")
        self._t, self._t_ids = sf.t[order], sf.ids[order]
        self._legacy: dict[tuple[int, float], int] | None = None

    def __len__(self) -> int:
        return len(self._idx) + len(self._legacy or ())

    def _load_legacy(self, f: Frame) -> dict[tuple[int, float], int]:
        keys = {f.source, str(Path(f.source).expanduser().resolve())} if f.source else set()
        keys.discard(self.identity)
        pairs: dict[tuple[int, float], int] = {}
        for key in sorted(keys):
            sf = self.store.source_frames(key)
            pairs.update(zip(zip(sf.frame_index.tolist(), sf.t.tolist()), sf.ids.tolist()))
        return pairs

    def find(self, f: Frame) -> int | None:
        """The id of a stored memory of this frame, or None."""
        if self._legacy is None:
            self._legacy = self._load_legacy(f)
        for keys, ids, v in ((self._idx, self._idx_ids, int(f.index)), (self._t, self._t_ids, float(f.t))):
            i = int(np.searchsorted(keys, v))
            if i < len(keys) and keys[i] == v:
                return int(ids[i])
        return self._legacy.get((int(f.index), float(f.t))) if self._legacy else None


def _counted(frames: Iterator[Frame], report: IngestReport, bar: Any, source: object) -> Iterator[Frame]:
    """Count the frames the source yields and move the progress bar by the frames it has seen
    (it skips some itself)."""
    for f in frames:
        report.frames_decoded += 1
        st = getattr(source, "stats", None)
        seen = int(st.frames_seen) if st is not None else report.frames_decoded
        bar.update(max(seen - bar.n, 0))
        yield f


def ingest(
    source: FrameSource,
    mem: Memory,
    keyframes: KeyframeConfig | None = None,
    batch_size: int = 16,
    progress: bool | None = None,
    wait: bool | float = False,
    mapper: FrameSink | None = None,
    text: str = "later",
) -> IngestReport:
    """Run a source into a memory; returns counts (also appended to the memory's manifest).

    Takes the memory's writer lock first (`wait` as in `Memory.acquire_writer`: another
    writer makes this fail at once, or wait). Frames already stored are skipped (see above).
    On a memory with OCR, `text="later"` (the default) reads the keyframes' text in a thread
    while the next frames are decoded and embedded (`Memory.add_frames`); the run returns once
    all of it is stored. `text="now"` reads it before each batch is stored.
    """
    cfg = keyframes if keyframes is not None else KeyframeConfig()
    if isinstance(batch_size, bool) or not isinstance(batch_size, int) or batch_size < 1:
        raise InputError(f"batch_size must be a whole number >= 1, got {batch_size!r}")
    mem.acquire_writer(wait)
    identity = source_identity(source)
    report = IngestReport(source=getattr(source, "name", str(source)), source_id=identity)
    stored = StoredFrames(mem.store, identity)
    stage = Admission(mem, cfg, mapper, text=text)
    show = sys.stderr.isatty() if progress is None else progress
    total = getattr(source, "frame_count", None)
    bar = tqdm(desc="ingest", unit="frame", total=total, disable=not show, file=sys.stderr)
    start = time.perf_counter()
    items: list[Frame | int] = []  # in source order: frames to store, ids of stored frames
    backlog: deque[int] = deque(maxlen=REPLAY)  # stored frames not yet replayed
    n_new = 0
    prefiltered = 0

    def flush() -> None:
        nonlocal n_new
        if not n_new:
            return
        replay = [*backlog, *(x for x in items if isinstance(x, int))]
        old = {r.id: _emb(r) for r in mem.store.get(replay, with_embeddings=True)} if replay else {}
        batch: list[tuple[str, Frame | Replay]] = [("", Replay(old[i])) for i in backlog]
        batch += [("", x if isinstance(x, Frame) else Replay(old[x])) for x in items]
        for x in items:
            if isinstance(x, Frame):
                x.source = identity
        for outcome in stage.admit(batch):
            if isinstance(outcome, str):
                report.skipped[outcome] = report.skipped.get(outcome, 0) + 1
            elif outcome is not None:
                report.first_id = outcome if report.first_id is None else report.first_id
                report.last_id = outcome
                report.kept += 1
        bar.set_postfix(kept=report.kept)
        items.clear()
        backlog.clear()
        n_new = 0

    try:
        for f in _counted(iter(source), report, bar, source):
            reason = stage.screen(f)
            if reason in (SKIP_NO_POSE, SKIP_TIME):
                report.skipped[reason] = report.skipped.get(reason, 0) + 1
                continue
            if reason is not None:
                prefiltered += 1
                continue
            done = stored.find(f)
            if done is not None:
                report.skipped[ALREADY] = report.skipped.get(ALREADY, 0) + 1
                if n_new:
                    items.append(done)
                else:
                    backlog.append(done)
                continue
            report.candidates += 1
            items.append(f)
            n_new += 1
            if n_new >= batch_size or len(items) >= 8 * batch_size:
                flush()
        flush()
        mem.wait_text()  # the text read meanwhile is stored before the run counts as done
    finally:
        if mapper is not None:
            mapper.close()
        st = getattr(source, "stats", None)
        if st is not None:  # frames the source skipped after the last one it yielded
            bar.update(max(int(st.frames_seen) - bar.n, 0))
        bar.close()
        report.seconds = time.perf_counter() - start
        if st is not None:
            report.frames_seen = int(st.frames_seen)
            report.raw_bytes = int(st.raw_bytes)
            for k, v in st.skipped.items():
                report.skipped[k] = report.skipped.get(k, 0) + int(v)
            report.warnings.extend(getattr(st, "warnings", []))
        else:
            report.frames_seen = report.frames_decoded
        report.frames_seen = max(report.frames_seen, report.frames_decoded)
        if prefiltered:
            report.skipped[PREFILTER] = prefiltered
        if report.kept or report.frames_seen:
            mem.record_ingest(report.as_dict())
    return report
