"""`Memory.info`: what a memory holds and what it costs, as `ravenmem info` prints it.

Counts, time span and extent, the embedder and store, bytes per memory with and without
thumbnails, and the compression against the raw video the ingest history recorded (each
recording counted once, however often it was ingested again).
"""

from __future__ import annotations

import math
from typing import Any

from .anchor import map_identity
from .core import Core
from .folder import thumbs_bytes


class Info(Core):
    """`Memory.info`."""

    def info(self) -> dict[str, Any]:
        """What `ravenmem info` prints: counts, span, extent, embedder, bytes per memory, compression."""
        st = dict(self.store.stats())
        n = int(st.get("count") or 0)  # type: ignore[call-overload]
        thumb_bytes = thumbs_bytes(self.path)
        store_bytes = int(st.get("bytes") or 0)  # type: ignore[call-overload]
        ingests = self.manifest.ingests
        seen, raw = _recording_totals(ingests)
        out: dict[str, Any] = {
            "path": str(self.path),
            "embedder": self.manifest.embedder,
            "dim": self.dim,
            "store": self.manifest.store,
            "ocr": self.ocr_enabled,
            "thumb_size": self.thumb_size,
            "memories": n,
            "frames_seen": seen,
            "keyframe_ratio": (seen / n) if n and seen else None,
            "store_bytes": store_bytes,
            "thumb_bytes": thumb_bytes,
            "bytes_per_memory": (store_bytes / n) if n else None,
            "bytes_per_memory_with_thumbs": ((store_bytes + thumb_bytes) / n) if n else None,
            "raw_video_bytes": raw,
            "compression_vs_raw": (raw / store_bytes) if raw and store_bytes else None,
            "compression_vs_raw_with_thumbs": (raw / (store_bytes + thumb_bytes))
            if raw and store_bytes
            else None,
        }
        for key in ("t_min", "t_max"):
            if key in st:
                out[key] = st[key]
        bounds = [st.get(f"{c}_{m}") for c in "xyz" for m in ("min", "max")]
        if n and all(isinstance(b, (int, float)) for b in bounds):
            xyz = [float(b) for b in bounds]  # type: ignore[arg-type]
            out["extent"] = {c: [xyz[2 * i], xyz[2 * i + 1]] for i, c in enumerate("xyz")}
        if n:
            out["duration_s"] = float(st["t_max"]) - float(st["t_min"])  # type: ignore[arg-type]
        groups = self.groups()
        if groups and n:  # consolidated memories (additive keys: absent on a memory never consolidated)
            live = set(self.store.select().tolist())  # rows a killed forget left are not counted
            out["consolidated"] = sum(1 for i in groups if i in live)
            out["memories_represented"] = n + sum(g[0] - 1 for i, g in groups.items() if i in live)
            self._span = None
            out["t_min"], out["t_max"] = self.time_span()  # what the merged memories saw, too
            out["duration_s"] = out["t_max"] - out["t_min"]
        out |= map_identity(self.manifest, self.path)  # where the poses are (REP 105)
        out["ingests"] = ingests
        return out


def _recording_totals(ingests: list[dict[str, Any]]) -> tuple[int, int]:
    """Frames seen and raw decoded bytes over the ingest history, each recording counted once:
    running an ingest again (a resume, or the same recording appended twice) sees the same
    frames again, so runs with the same source identity count as their largest run. Runs
    without an identity (live adds) are all different and add up."""
    seen = raw = 0
    per_source: dict[str, tuple[int, int]] = {}
    for r in ingests:
        frames, size = _count(r.get("frames_seen")), _count(r.get("raw_bytes"))
        sid = r.get("source_id")
        if isinstance(sid, str) and sid:
            old = per_source.get(sid, (0, 0))
            per_source[sid] = (max(old[0], frames), max(old[1], size))
        else:
            seen, raw = seen + frames, raw + size
    return seen + sum(f for f, _ in per_source.values()), raw + sum(b for _, b in per_source.values())


def _count(v: object) -> int:
    """A count from the ingest history; anything that is not a finite number counts 0."""
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        return 0
    return int(v)
