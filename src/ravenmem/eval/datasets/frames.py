"""Frame sources for benchmark episodes: image lists with known times/poses, and videos.

Benchmarks give frames as files (RAVEN-QA, NaVQA conversions) or as one video per episode
(FindingDory), with times and poses from side tables rather than from a pose track, so the
ingest sources do not fit them. These yield `Frame`s lazily, one decoded image at a time, and
count unreadable frames instead of failing a whole run on one bad file.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Iterable, Iterator
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path

import numpy as np

from ...errors import InputError
from ...imageio import read_image
from ...ingest.base import SourceStats
from ...types import Frame, Pose

# Frames whose files carry only a time of day (HH:MM:SS) are placed on this UTC date, so that
# `mem.parse_time("08:15:00")` ("that time on the recording's day") finds them.
BASE_DAY = datetime(2000, 1, 1, tzinfo=timezone.utc).timestamp()
IMAGE_EXTS = (".jpg", ".jpeg", ".png", ".bmp", ".webp")


@dataclass
class FrameRef:
    """Where one frame comes from and where/when it was taken (image decoded on iteration)."""

    t: float
    pose: Pose | None
    path: Path | None = None
    load: Callable[[], np.ndarray] | None = None
    index: int = 0


class RefSource:
    """A FrameSource over a list of FrameRefs (files or loader callables)."""

    def __init__(self, name: str, refs: list[FrameRef]) -> None:
        self.name = name
        self.refs = refs
        self.stats = SourceStats()

    def __iter__(self) -> Iterator[Frame]:
        self.stats = SourceStats()
        for ref in self.refs:
            self.stats.frames_seen += 1
            try:
                img = ref.load() if ref.load is not None else read_image(ref.path)  # type: ignore[arg-type]
            except (InputError, OSError, ValueError) as e:
                self.stats.skip(f"unreadable frame ({type(e).__name__})")
                continue
            self.stats.raw_bytes += int(img.nbytes)
            self.stats.frames_yielded += 1
            yield Frame(
                image=img,
                t=ref.t,
                pose=ref.pose,
                source=self.name,
                index=ref.index,
                path=str(ref.path) if ref.path else None,
            )


class VideoSource:
    """Decode a video file frame by frame; frame i gets time `times[i]` and pose `poses[i]`."""

    def __init__(
        self, name: str, path: Path, time_of: Callable[[int], float], pose_of: Callable[[int], Pose | None]
    ) -> None:
        self.name = name
        self.path = path
        self.time_of = time_of
        self.pose_of = pose_of
        self.stats = SourceStats()

    def __iter__(self) -> Iterator[Frame]:
        import av

        self.stats = SourceStats()
        try:
            container = av.open(str(self.path))
        except (av.error.FFmpegError, OSError) as e:  # type: ignore[attr-defined]
            raise InputError(f"video {self.path} cannot be opened: {e}") from e
        with container:
            for i, vf in enumerate(container.decode(video=0)):
                self.stats.frames_seen += 1
                img = vf.to_ndarray(format="rgb24")
                self.stats.raw_bytes += int(img.nbytes)
                self.stats.frames_yielded += 1
                yield Frame(image=img, t=self.time_of(i), pose=self.pose_of(i), source=self.name, index=i)


def video_frame_count(path: Path) -> int:
    """Number of frames in a video (decoded count when the container does not say)."""
    import av

    try:
        with av.open(str(path)) as c:
            n = int(c.streams.video[0].frames or 0)
            if n > 0:
                return n
            return sum(1 for _ in c.decode(video=0))
    except (av.error.FFmpegError, OSError, IndexError) as e:  # type: ignore[attr-defined]
        raise InputError(f"video {path} cannot be read: {e}") from e


class Subsampled:
    """Keep every `stride`-th frame and stop after `limit` frames of the original (studies)."""

    def __init__(self, inner: Iterable[Frame], stride: int = 1, limit: int | None = None) -> None:
        if stride < 1:
            raise InputError(f"stride must be >= 1, got {stride}")
        self.inner = inner
        self.stride = stride
        self.limit = limit
        self.name = getattr(inner, "name", "frames")
        self.stats = SourceStats()

    def __iter__(self) -> Iterator[Frame]:
        self.stats = SourceStats()
        for i, f in enumerate(self.inner):
            if self.limit is not None and i >= self.limit:
                break
            self.stats.frames_seen += 1
            self.stats.raw_bytes += int(f.image.nbytes)
            if i % self.stride == 0:
                self.stats.frames_yielded += 1
                yield f
        inner_stats = getattr(self.inner, "stats", None)
        if inner_stats is not None:
            for k, v in inner_stats.skipped.items():
                self.stats.skip(k, v)


def natural_key(name: str) -> list[object]:
    """Sort key that orders frame_2 before frame_10."""
    return [int(p) if p.isdigit() else p.lower() for p in re.split(r"(\d+)", name)]


def list_images(folder: Path) -> list[Path]:
    return sorted(
        (p for p in folder.iterdir() if p.suffix.lower() in IMAGE_EXTS and p.is_file()),
        key=lambda p: natural_key(p.name),
    )


def parse_hms(text: str, where: str) -> float:
    """'HH:MM:SS[.f]', 'MM:SS' or 'SS' -> seconds after midnight."""
    try:
        parts = [float(p) for p in str(text).strip().split(":")]
    except ValueError:
        raise InputError(f"{where}: {text!r} is not a HH:MM:SS time") from None
    if not 1 <= len(parts) <= 3 or min(parts) < 0:
        raise InputError(f"{where}: {text!r} is not a HH:MM:SS time")
    while len(parts) < 3:
        parts.insert(0, 0.0)
    return parts[0] * 3600 + parts[1] * 60 + parts[2]


def interpolate_times(n: int, anchors: dict[int, float], rate_hz: float) -> list[float]:
    """Times for n frames in order: linear between anchor frames, `rate_hz` outside or without any.

    Anchors are (frame index -> seconds). Between two anchors times are interpolated by index;
    before the first / after the last they continue at the rate of the nearest anchored segment
    (or `rate_hz` when there is only one anchor), so times always increase with frame order.
    """
    if n == 0:
        return []
    idx = sorted(anchors)
    if not idx:
        return [i / rate_hz for i in range(n)]
    xs = np.asarray(idx, dtype=float)
    ys = np.asarray([anchors[i] for i in idx], dtype=float)
    if np.any(np.diff(ys) <= 0):
        raise InputError("frame times from the timestamp map do not increase with frame order")
    out = np.interp(np.arange(n, dtype=float), xs, ys)
    lo_slope = (ys[1] - ys[0]) / (xs[1] - xs[0]) if len(xs) > 1 else 1.0 / rate_hz
    hi_slope = (ys[-1] - ys[-2]) / (xs[-1] - xs[-2]) if len(xs) > 1 else 1.0 / rate_hz
    before = np.arange(n) < xs[0]
    after = np.arange(n) > xs[-1]
    out[before] = ys[0] - (xs[0] - np.arange(n)[before]) * lo_slope
    out[after] = ys[-1] + (np.arange(n)[after] - xs[-1]) * hi_slope
    return [float(v) for v in out]


def interpolate_positions(n: int, known: dict[int, list[float]]) -> list[list[float] | None]:
    """Positions for n frames: known ones kept, others linear by index between neighbours,
    held constant before the first / after the last known one. None for all when none known."""
    if not known:
        return [None] * n
    idx = sorted(known)
    arr = np.asarray([list(known[i]) + [0.0] * (3 - len(known[i])) for i in idx], dtype=float)
    out = np.stack([np.interp(np.arange(n, dtype=float), idx, arr[:, k]) for k in range(3)], axis=1)
    return [[float(v) for v in row] for row in out]
