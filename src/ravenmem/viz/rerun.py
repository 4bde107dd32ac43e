"""A rerun recording of a memory: the trajectory in 3D, every keyframe on the timeline as a
posed camera with its thumbnail, and the hits of a query marked, for the rerun viewer.

Entities (world frame = the memory's map frame, z up):
- `world/trajectory` (static): the path through every memory, in time order;
- `world/memories` (static): one point per memory;
- `world/camera` on the `time` (Unix time) and `memory` (id) timelines: the keyframe's pose
  (translation + rotation), a pinhole and `world/camera/image`, the thumbnail as stored (JPEG
  bytes, not re-encoded), at most `max_images` of them (evenly spread; every pose is logged);
- `world/hits` (static, with a query): the hits' positions, labelled with rank and score, and
  `hits/NN` their thumbnails; `query` a text document with the query and the hits.

The recording is built in memory and written to the .rrd crash-safely (`fsio.atomic_write`);
`ravenmem view --spawn` then opens that file in the rerun viewer.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError, require
from ..fsio import atomic_write
from ..memory import Memory
from ..timeparse import fmt_time
from ..types import Hit, MemoryRecord

APP_ID = "ravenmem"
CAMERA_AXES = ("flu", "rdf")


@dataclass
class ViewSummary:
    """What went into the recording (the CLI prints it)."""

    memories: int = 0
    images: int = 0
    hits: int = 0
    entities: list[str] = field(default_factory=list)
    out: str | None = None


def _quat(rec: MemoryRecord) -> list[float]:
    """x, y, z, w of a memory's orientation (from its yaw when it has no full quaternion)."""
    if rec.pose.quat is not None:
        return list(rec.pose.quat)
    return [0.0, 0.0, math.sin(rec.pose.yaw / 2), math.cos(rec.pose.yaw / 2)]


def _thumb(mem: Memory, rec: MemoryRecord) -> bytes | None:
    """The memory's picture file, when it is a JPEG or PNG inside the memory folder."""
    p = mem.image_file(rec)
    if p is None or p.suffix.lower() not in (".jpg", ".jpeg", ".png"):
        return None
    try:
        return p.read_bytes()
    except OSError:
        return None


def _media(data: bytes) -> str:
    return "image/png" if data[:8] == b"\x89PNG\r\n\x1a\n" else "image/jpeg"


def record(
    mem: Memory,
    out: str | Path,
    hits: Sequence[Hit] = (),
    query: str | None = None,
    max_images: int = 5000,
    camera_axes: str = "flu",
) -> ViewSummary:
    """Record the memory (see the module docstring) to the .rrd file `out`.

    camera_axes: how the stored orientation's camera looks: `flu` (x forward, z up: a robot's
    base_link, the usual ROS pose) or `rdf` (z forward, y down: an optical frame, as TUM's
    ground truth)."""
    if camera_axes not in CAMERA_AXES:
        raise InputError(f"camera axes must be one of {', '.join(CAMERA_AXES)}, got {camera_axes!r}")
    if max_images < 0:
        raise InputError(f"max images must be >= 0, got {max_images}")
    rr: Any = require("rerun", "view")
    rec = rr.RecordingStream(APP_ID, recording_id=f"{APP_ID}:{Path(mem.path).name}")
    sink = rr.memory_recording(rec)
    summary = _log_memory(rr, rec, mem, hits, query, max_images, camera_axes)
    rec.flush()
    try:
        atomic_write(out, sink.drain_as_bytes())
    except OSError as e:
        raise InputError(f"cannot write the recording {out}: {e.strerror or e}") from None
    summary.out = str(out)
    return summary


def _log_memory(
    rr: Any, rec: Any, mem: Memory, hits: Sequence[Hit], query: str | None, max_images: int, camera_axes: str
) -> ViewSummary:
    summary = ViewSummary()
    recs = mem.all_records()
    summary.memories = len(recs)
    if not recs:
        return summary
    xyz = np.asarray([r.pose.xyz for r in recs], dtype=np.float64)
    rec.log("world", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    rec.log("world/trajectory", rr.LineStrips3D([xyz], colors=[[90, 140, 230]], radii=[0.01]), static=True)
    rec.log("world/memories", rr.Points3D(xyz, colors=[[60, 60, 70]], radii=[0.02]), static=True)
    times = rr.TimeColumn("time", timestamp=np.asarray([r.t for r in recs]))
    ids = rr.TimeColumn("memory", sequence=np.asarray([r.id for r in recs], dtype=np.int64))
    rec.send_columns(
        "world/camera",
        indexes=[times, ids],
        columns=rr.Transform3D.columns(translation=xyz, quaternion=[_quat(r) for r in recs]),
    )
    axes = rr.ViewCoordinates.FLU if camera_axes == "flu" else rr.ViewCoordinates.RDF
    tw, th = _thumb_size(mem, recs)
    rec.log(
        "world/camera",
        rr.Pinhole(focal_length=float(tw), width=tw, height=th, camera_xyz=axes, image_plane_distance=0.25),
        static=True,
    )
    stride = max(1, math.ceil(len(recs) / max(1, max_images)))
    pics = [(r, b) for r in recs[::stride] if (b := _thumb(mem, r)) is not None] if max_images else []
    if pics:
        rec.send_columns(
            "world/camera/image",
            indexes=[
                rr.TimeColumn("time", timestamp=np.asarray([r.t for r, _ in pics])),
                rr.TimeColumn("memory", sequence=np.asarray([r.id for r, _ in pics], dtype=np.int64)),
            ],
            columns=rr.EncodedImage.columns(
                blob=[b for _, b in pics], media_type=[_media(b) for _, b in pics]
            ),
        )
    summary.images = len(pics)
    summary.entities = ["world/trajectory", "world/memories", "world/camera"]
    summary.entities += ["world/camera/image"] if pics else []
    if query is not None:
        _log_hits(rr, rec, mem, hits, query, summary)
    return summary


def _log_hits(rr: Any, rec: Any, mem: Memory, hits: Sequence[Hit], query: str, summary: ViewSummary) -> None:
    lines = [
        f"# {query}",
        "",
        "| rank | id | score | time (UTC) | x | y | z |",
        "|---|---|---|---|---|---|---|",
    ]
    for i, h in enumerate(hits, 1):
        r = h.memory
        score = "" if h.score is None else f"{h.score:.3f}"
        lines.append(
            f"| {i} | {r.id} | {score} | {fmt_time(r.t)} | {r.pose.x:.2f} | {r.pose.y:.2f} | {r.pose.z:.2f} |"
        )
    rec.log("query", rr.TextDocument("\n".join(lines), media_type="text/markdown"), static=True)
    summary.entities.append("query")
    summary.hits = len(hits)
    if not hits:
        return
    labels = [f"#{i} {h.score:.2f}" if h.score is not None else f"#{i}" for i, h in enumerate(hits, 1)]
    rec.log(
        "world/hits",
        rr.Points3D([h.memory.pose.xyz for h in hits], colors=[[220, 40, 40]], radii=[0.06], labels=labels),
        static=True,
    )
    summary.entities.append("world/hits")
    for i, h in enumerate(hits, 1):
        data = _thumb(mem, h.memory)
        if data is not None:
            rec.log(f"hits/{i:02d}", rr.EncodedImage(contents=data, media_type=_media(data)), static=True)
            summary.entities.append(f"hits/{i:02d}")


def _thumb_size(mem: Memory, recs: Sequence[MemoryRecord]) -> tuple[int, int]:
    """Width and height of the first readable picture (for the pinhole), else 4:3."""
    for r in recs[:20]:
        img = mem.load_image(r)
        if img is not None:
            return int(img.shape[1]), int(img.shape[0])
    return 320, 240
