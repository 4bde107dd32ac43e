"""TUM RGB-D benchmark folder: `rgb.txt` + `groundtruth.txt` (+ optional `depth.txt`).

Layout (the benchmark's own): `rgb.txt` and `depth.txt` hold `timestamp filename` rows with
paths relative to the folder; `groundtruth.txt` holds `timestamp tx ty tz qx qy qz qw` at
~100 Hz. A frame's pose is, by default, the ground-truth row nearest in time within 0.02 s (the
benchmark's own association rule); frames in a ground-truth gap are skipped and counted.
`pose_match="interpolate"` slerps between the bracketing rows instead.
Depth PNGs are 16-bit, 5000 units per metre; 0 (no measurement) becomes NaN.

The ground truth is the colour camera's optical frame (x right, y down, z forward) in the
motion-capture frame, whose axes are not tied to gravity: the source says so
(`camera_extrinsic = "optical"`) and the mapper finds the floor from the depth. The camera's
intrinsics come from `intrinsics=` (a preset name or fx,fy,cx,cy) or from the folder's name
(`freiburg1`/`fr1` ... -> the benchmark's published values); see `ingest/depth.py`.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from ..errors import InputError
from ..fsio import read_text
from ..types import Frame, Intrinsics, check_time
from .base import SOURCES, SourceConfig, SourceStats
from .common import check_flag, check_gap, check_intrinsics, existing, pose_track_arg, read_rgb
from .depth import preset_from_name, read_depth_file
from .identity import file_head, make_identity
from .poses import PoseTrack, check_match_mode

DEPTH_SCALE = 5000.0


def read_index(path: Path) -> list[tuple[float, str]]:
    """Parse a TUM `timestamp filename` list; bad rows raise InputError naming file and line."""
    out: list[tuple[float, str]] = []
    for n, raw in enumerate(read_text(path, what="TUM list", errors="replace").splitlines(), start=1):
        line = raw.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.split()
        if len(parts) < 2:
            raise InputError(f"{path} line {n}: expected 'timestamp filename', found {line!r}")
        try:
            t = float(parts[0])
        except ValueError:
            raise InputError(f"{path} line {n}, column 'timestamp': not a number: {parts[0]!r}") from None
        check_time(t, f"{path} line {n}, column 'timestamp'")
        out.append((t, parts[1]))
    return out


def read_depth(path: Path) -> np.ndarray | None:
    """A TUM depth PNG as float32 metres (NaN where the sensor had no reading), None if unreadable."""
    return read_depth_file(path, DEPTH_SCALE)


@dataclass
class TumConfig(SourceConfig):
    """A TUM RGB-D folder (`tum:PATH`). groundtruth (or `poses`, the name the other sources
    use): the pose track instead of the folder's groundtruth.txt; pose_match `nearest` within
    max_gap s (the benchmark's rule) or `interpolate`; depth: read depth.txt's images (paired
    within depth_max_gap s); intrinsics: a preset or fx,fy,cx,cy (default: from the folder's
    name)."""

    groundtruth: str | Path | PoseTrack | None = None
    pose_match: str = "nearest"
    max_gap: float | None = 0.02
    depth: bool = True
    depth_max_gap: float = 0.02
    poses: str | Path | PoseTrack | None = None
    intrinsics: Intrinsics | str | None = None

    kind: ClassVar[str] = "tum"

    def __post_init__(self) -> None:
        check_match_mode(self.pose_match)
        self.max_gap = check_gap("tum", "max_gap", self.max_gap)
        if self.pose_match == "nearest" and self.max_gap is None:
            raise InputError("tum: nearest pose matching needs max_gap (seconds)")
        check_flag("tum", "depth", self.depth)
        self.depth_max_gap = check_gap("tum", "depth_max_gap", self.depth_max_gap) or 0.0
        self.intrinsics = check_intrinsics(self.intrinsics)


class TumSource:
    """Frames of a TUM RGB-D sequence folder, posed from its ground truth (options: `TumConfig`)."""

    def __init__(self, path: str | Path | TumConfig, **options: Any) -> None:
        cfg = self.config = TumConfig.of(path, **options)
        self.root = existing(cfg.path, "TUM folder", want_dir=True)
        self.name = f"tum:{self.root.name}"
        self.stats = SourceStats()
        rgb = self.root / "rgb.txt"
        if not rgb.is_file():
            raise InputError(f"{self.root}: not a TUM RGB-D folder (no rgb.txt)")
        self.entries = read_index(rgb)
        if not self.entries:
            raise InputError(f"{rgb}: lists no frames")
        groundtruth = cfg.groundtruth if cfg.groundtruth is not None else cfg.poses
        gt = groundtruth if groundtruth is not None else self.root / "groundtruth.txt"
        if groundtruth is None and not (self.root / "groundtruth.txt").is_file():
            raise InputError(f"{self.root}: no groundtruth.txt (pass groundtruth=FILE with poses)")
        self.track = pose_track_arg(gt, sort=True)
        self.pose_match = check_match_mode(cfg.pose_match)
        self.max_gap = cfg.max_gap
        self.depth_entries: list[tuple[float, str]] = []
        if cfg.depth and (self.root / "depth.txt").is_file():
            self.depth_entries = read_index(self.root / "depth.txt")
        self.depth_max_gap = cfg.depth_max_gap
        self.camera_extrinsic = "optical"
        self.intrinsics: Intrinsics | None = cfg.intrinsics or preset_from_name(self.root.name)  # type: ignore[assignment]

    @property
    def frame_count(self) -> int:
        return len(self.entries)

    def identity(self) -> str:
        """The folder's name and the start of its rgb.txt (timestamps and file names)."""
        return make_identity("tum", self.root.name, [file_head(self.root / "rgb.txt", 1 << 16)])

    def _depth_index(self) -> np.ndarray:
        """For each rgb entry, the index of the nearest depth entry within the gap, else -1."""
        if not self.depth_entries:
            return np.full(len(self.entries), -1)
        dt = np.array([t for t, _ in self.depth_entries])
        order = np.argsort(dt)
        dt = dt[order]
        ts = np.array([t for t, _ in self.entries])
        hi = np.clip(np.searchsorted(dt, ts), 0, len(dt) - 1)
        lo = np.clip(hi - 1, 0, len(dt) - 1)
        pick = np.where(np.abs(dt[lo] - ts) <= np.abs(dt[hi] - ts), lo, hi)
        return np.where(np.abs(dt[pick] - ts) <= self.depth_max_gap, order[pick], -1)

    def __iter__(self) -> Iterator[Frame]:
        self.stats = SourceStats()
        depth_idx = self._depth_index()
        for i, (t, rel) in enumerate(self.entries):
            self.stats.frames_seen += 1
            m = self.track.match(t, self.pose_match, self.max_gap)
            if isinstance(m, str):
                self.stats.skip(m)
                continue
            image = read_rgb(self.root / rel)
            if isinstance(image, str):
                self.stats.skip(image)
                continue
            self.stats.raw_bytes += image.size
            depth = None
            if depth_idx[i] >= 0:
                depth = read_depth(self.root / self.depth_entries[depth_idx[i]][1])
            self.stats.frames_yielded += 1
            yield Frame(
                image=image,
                t=t,
                pose=m,
                source=str(self.root),
                index=i,
                depth=depth,
                path=str(self.root / rel),
            )


@SOURCES.register("tum")
def _tum(spec: str | TumConfig, **kwargs: Any) -> TumSource:
    return TumSource(TumConfig.of(spec, **kwargs))
