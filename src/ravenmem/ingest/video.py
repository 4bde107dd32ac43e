"""Video file + pose track source (PyAV), decoded one frame at a time.

Frame time is `start_time + pts seconds`: by default start_time is 0.0, so frames carry the
video's own clock and the pose file must use the same clock (seconds from the video's start).
Give `start_time` as epoch seconds or ISO 8601 to put both on the wall clock (the pose file then
holds epoch seconds), or `"creation_time"` to read the container's creation_time tag. That tag
is opt-in because cameras and muxers disagree on whether it marks the start or the end of the
recording, or the time the file was re-encoded.
"""

from __future__ import annotations

import math
from collections.abc import Iterator
from dataclasses import dataclass
from fractions import Fraction
from pathlib import Path
from typing import Any, ClassVar

import av

from ..errors import InputError
from ..types import Frame
from .base import SOURCES, SourceConfig, SourceStats
from .common import check_flag, check_gap, check_positive, existing, parse_start_time, pose_track_arg
from .identity import file_head, make_identity
from .poses import PoseTrack, check_match_mode

VIDEO_EXTS = (".mp4", ".mkv", ".avi", ".mov", ".webm", ".m4v")

SKIP_CORRUPT = "corrupt video frame"
SKIP_TRUNCATED = "unreadable video data (decoding stopped)"
SKIP_FPS = "above source fps"
SKIP_ENDED_EARLY = "missing from the file (it ended early)"


def _open(path: Path) -> Any:
    try:
        container = av.open(str(path))
    except av.FFmpegError as e:
        raise InputError(f"{path}: not a readable video ({e.strerror or type(e).__name__})") from None
    if not container.streams.video:
        container.close()
        raise InputError(f"{path}: has no video stream")
    return container


@dataclass
class VideoConfig(SourceConfig):
    """A video file (`video:PATH`) and its pose track on the same clock. start_time: seconds,
    ISO 8601 or `creation_time` (see the module docstring); pose_match `interpolate` or
    `nearest` (within max_gap s, 0.05 when not given); fps: decode at most this many frames per
    second; allow_no_pose: frames without a pose (they are then dropped by ingest);
    sort_poses: sort a pose file written out of order."""

    poses: str | Path | PoseTrack | None = None
    start_time: float | str = 0.0
    pose_match: str = "interpolate"
    max_gap: float | None = None
    fps: float | None = None
    allow_no_pose: bool = False
    sort_poses: bool = False

    kind: ClassVar[str] = "video"

    def __post_init__(self) -> None:
        check_match_mode(self.pose_match)
        self.max_gap = check_gap("video", "max_gap", self.max_gap)
        if self.pose_match == "nearest" and self.max_gap is None:
            self.max_gap = 0.05
        self.fps = check_positive("video", "fps", self.fps)
        check_flag("video", "allow_no_pose", self.allow_no_pose)
        check_flag("video", "sort_poses", self.sort_poses)


class VideoSource:
    """Frames of a video file with poses interpolated from a pose track on the same clock
    (options: `VideoConfig`)."""

    def __init__(self, path: str | Path | VideoConfig, **options: Any) -> None:
        cfg = self.config = VideoConfig.of(path, **options)
        self.path = existing(cfg.path, "video file", want_dir=False)
        self.name = f"video:{self.path.name}"
        self.stats = SourceStats()
        self.pose_match = check_match_mode(cfg.pose_match)
        self.max_gap = cfg.max_gap
        self.fps = cfg.fps
        poses, start_time = cfg.poses, cfg.start_time
        if poses is None and not cfg.allow_no_pose:
            raise InputError(
                f"{self.path}: a video needs a pose track (poses=FILE, CSV or TUM); "
                "frames without a pose cannot be placed in the map"
            )
        self.track = None if poses is None else pose_track_arg(poses, sort=cfg.sort_poses)
        container = _open(self.path)
        try:
            self.frame_count = _expected_frames(container)
            self.exact_count = bool(container.streams.video[0].frames)
            self.duration = container.duration / av.time_base if container.duration else None
            if isinstance(start_time, str) and start_time.strip().lower() == "creation_time":
                tag = container.metadata.get("creation_time") or container.streams.video[0].metadata.get(
                    "creation_time"
                )
                if not tag:
                    raise InputError(f"{self.path}: no creation_time tag; pass start_time as epoch seconds")
                self.start_time = parse_start_time(tag)
            else:
                self.start_time = parse_start_time(start_time)
        finally:
            container.close()

    def identity(self) -> str:
        """The file's name and first MiB (which, for an mp4, holds its index), so a fuller copy
        of a truncated file is the same recording and two clips with one name are not."""
        return make_identity("video", self.path.name, [file_head(self.path)])

    def _ended_early(self, last_t: float | None, rate: float) -> None:
        """Compare what was decoded with what the container promised: a cut-off download or a
        recording still being written decodes cleanly up to where it stops, without an error.
        A shortfall of one or two frames is not reported (edit lists may hide a frame or two)."""
        seen, expected = self.stats.frames_seen, self.frame_count
        missing = 0
        if self.exact_count and expected is not None:
            missing = expected - seen
        elif last_t is not None and self.duration is not None:
            # no frame count in the container (mkv, webm): the duration says how long it should be
            gap = self.duration - (last_t - self.start_time) - 1.0 / rate
            missing = int(round(gap * rate)) if gap > 1.0 else 0
        stopped = SKIP_TRUNCATED in self.stats.skipped
        if missing <= 2 and not stopped:
            return
        if missing > 0:
            self.stats.skip(SKIP_ENDED_EARLY, missing)
        of = ""
        if expected is not None:
            of = f" of {'' if self.exact_count else 'about '}{expected}"
        self.stats.warnings.append(
            f"{self.path}: the file ended early: {seen}{of} frames decoded "
            "(cut off while copying, or still being written?)"
        )

    def _decoded(self, container: Any) -> Iterator[Any]:
        """Decoded av.VideoFrames; a packet that fails to decode is skipped and counted."""
        stream = container.streams.video[0]
        stream.thread_type = "AUTO"
        packets = container.demux(stream)
        while True:
            try:
                packet = next(packets)
            except StopIteration:
                return
            except av.FFmpegError:
                self.stats.skip(SKIP_TRUNCATED)
                return
            try:
                decoded = packet.decode()
            except av.FFmpegError:
                self.stats.frames_seen += 1
                self.stats.skip(SKIP_CORRUPT)
                continue
            yield from decoded

    def __iter__(self) -> Iterator[Frame]:
        self.stats = SourceStats()
        container = _open(self.path)
        try:
            stream = container.streams.video[0]
            tb = stream.time_base or Fraction(1, 90000)
            rate = float(stream.average_rate or 30)
            index = -1
            last_t: float | None = None
            t_first: float | None = None
            last_slot = -1
            for vf in self._decoded(container):
                index += 1
                self.stats.frames_seen += 1
                self.stats.raw_bytes += int(vf.width) * int(vf.height) * 3
                if vf.pts is not None:
                    tv = float(vf.pts * tb)
                else:
                    tv = (last_t - self.start_time + 1.0 / rate) if last_t is not None else 0.0
                t = self.start_time + tv
                last_t = t
                pose = None
                if self.track is not None:
                    m = self.track.match(t, self.pose_match, self.max_gap)
                    if isinstance(m, str):
                        self.stats.skip(m)
                        continue
                    pose = m
                if self.fps is not None:
                    t_first = t if t_first is None else t_first
                    slot = math.floor((t - t_first) * self.fps + 1e-6)
                    if slot <= last_slot:
                        self.stats.skip(SKIP_FPS)
                        continue
                    last_slot = slot
                try:
                    image = vf.to_ndarray(format="rgb24")
                except (av.FFmpegError, ValueError):
                    self.stats.skip(SKIP_CORRUPT)
                    continue
                self.stats.frames_yielded += 1
                yield Frame(image=image, t=t, pose=pose, source=str(self.path), index=index)
            self._ended_early(last_t, rate)
        finally:
            container.close()


def _expected_frames(container: Any) -> int | None:
    """Frames the container says the stream holds: its frame count (mp4, mov) or, failing
    that, duration x average rate (mkv, webm: an estimate); None when it says neither."""
    stream = container.streams.video[0]
    if stream.frames:
        return int(stream.frames)
    rate = float(stream.average_rate or 0)
    if container.duration and rate > 0:
        return max(1, int(round(container.duration / av.time_base * rate)))
    return None


@SOURCES.register("video")
def _video(spec: str | VideoConfig, **kwargs: Any) -> VideoSource:
    return VideoSource(VideoConfig.of(spec, **kwargs))
