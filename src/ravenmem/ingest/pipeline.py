"""source -> keyframes -> embedder -> store, in batches, each batch durable when written.

Cheap selection (stride, rate, pose motion) runs before the embedder; novelty by embedding
runs after it, on vectors that are then stored as they are (no frame is embedded twice).
A killed ingest keeps every batch that was written; re-running appends.
"""

from __future__ import annotations

import sys
import time
from collections.abc import Iterator
from dataclasses import asdict, dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from tqdm import tqdm

from ..types import Frame
from .base import FrameSource
from .keyframes import DROP_SIMILAR, KeyframeConfig, Keyframer

if TYPE_CHECKING:
    from ..memory import Memory


@dataclass
class IngestReport:
    """What one ingest run saw, kept and dropped (with reasons)."""

    source: str
    frames_seen: int = 0
    frames_decoded: int = 0
    candidates: int = 0
    kept: int = 0
    skipped: dict[str, int] = field(default_factory=dict)
    raw_bytes: int = 0
    seconds: float = 0.0
    first_id: int | None = None
    last_id: int | None = None

    @property
    def keyframes_per_s(self) -> float:
        return self.kept / self.seconds if self.seconds > 0 else 0.0

    def as_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["keyframes_per_s"] = round(self.keyframes_per_s, 3)
        return d


def _posed(frames: Iterator[Frame], report: IngestReport) -> Iterator[Frame]:
    """Drop frames with no pose or a timestamp that goes back in time (counted, never guessed)."""
    last_t = -float("inf")
    for f in frames:
        report.frames_decoded += 1
        if f.pose is None:
            report.skipped["no pose"] = report.skipped.get("no pose", 0) + 1
            continue
        if not np.isfinite(f.t) or f.t < last_t:
            report.skipped["non-monotonic timestamp"] = report.skipped.get("non-monotonic timestamp", 0) + 1
            continue
        last_t = f.t
        yield f


def ingest(
    source: FrameSource,
    mem: Memory,
    keyframes: KeyframeConfig | None = None,
    batch_size: int = 16,
    progress: bool | None = None,
) -> IngestReport:
    """Run a source into a memory; returns counts (also appended to the memory's manifest)."""
    cfg = keyframes or KeyframeConfig()
    report = IngestReport(source=getattr(source, "name", str(source)))
    kf = Keyframer(cfg)
    show = sys.stderr.isatty() if progress is None else progress
    bar = tqdm(desc="ingest", unit="frame", disable=not show, file=sys.stderr)
    start = time.perf_counter()
    batch: list[Frame] = []

    def flush() -> None:
        if not batch:
            return
        emb = mem.embedder.embed_images([f.image for f in batch])
        keep = [i for i in range(len(batch)) if kf.post(emb[i]) is None]
        if len(keep) < len(batch):
            report.skipped[DROP_SIMILAR] = report.skipped.get(DROP_SIMILAR, 0) + len(batch) - len(keep)
        if keep:
            ids = mem.add_frames([batch[i] for i in keep], embeddings=emb[keep])
            report.first_id = ids[0] if report.first_id is None else report.first_id
            report.last_id = ids[-1]
            report.kept += len(ids)
        bar.set_postfix(kept=report.kept)
        batch.clear()

    try:
        for f in _posed(iter(source), report):
            if kf.pre(f) is not None:
                continue
            report.candidates += 1
            batch.append(f)
            bar.update(1)
            if len(batch) >= batch_size:
                flush()
        flush()
    finally:
        bar.close()
        report.seconds = time.perf_counter() - start
        st = getattr(source, "stats", None)
        if st is not None:
            report.frames_seen = int(st.frames_seen)
            report.raw_bytes = int(st.raw_bytes)
            for k, v in st.skipped.items():
                report.skipped[k] = report.skipped.get(k, 0) + int(v)
        else:
            report.frames_seen = report.frames_decoded
        report.frames_seen = max(report.frames_seen, report.frames_decoded)
        prefilter_dropped = (
            report.frames_decoded
            - sum(v for k, v in report.skipped.items() if k in ("no pose", "non-monotonic timestamp"))
            - report.candidates
        )
        if prefilter_dropped > 0:
            report.skipped["keyframe selection (stride/rate/motion)"] = prefilter_dropped
        if report.kept or report.frames_seen:
            mem.record_ingest(report.as_dict())
    return report
