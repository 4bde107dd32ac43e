"""The source axis: anything that yields timestamped, posed RGB frames, streaming.

A source must never load a whole recording into RAM: it yields frames one at a time.
It counts what it had to drop (unreadable frames, frames outside the pose track) in
`stats` so that `ravenmem ingest` and `info` can report them instead of guessing, and puts
what the user must hear about (a video that ended early) in `stats.warnings`.

Two optional members, which every built-in source has: `identity()`, the recording's identity
independent of its path (see `ingest.identity`; ingest uses it to skip frames already stored),
and `frame_count`, the number of frames the recording says it holds (None when it cannot tell
cheaply), for the progress bar's total and ETA.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

from ..registry import Registry
from ..types import Frame


@dataclass
class SourceStats:
    """What a source saw and dropped, with a reason for each drop."""

    frames_seen: int = 0
    frames_yielded: int = 0
    skipped: dict[str, int] = field(default_factory=dict)
    raw_bytes: int = 0  # decoded RGB bytes of every frame seen (for the compression factor)
    warnings: list[str] = field(default_factory=list)

    def skip(self, reason: str, n: int = 1) -> None:
        self.skipped[reason] = self.skipped.get(reason, 0) + n


@runtime_checkable
class FrameSource(Protocol):
    name: str
    stats: SourceStats

    def __iter__(self) -> Iterator[Frame]: ...


@runtime_checkable
class FrameSink(Protocol):
    """Fed every posed frame that carries depth, before keyframe selection: the map builder
    (`ravenmem.nav.mapping.MapBuilder`) is one. `close` is called once, when the run ends."""

    def add(self, frame: Frame) -> bool: ...

    def close(self) -> None: ...


# The bag source lives with the other ROS code (`ravenmem.ros.bag`): named here, it is imported
# only when a bag is opened.
SOURCES: Registry[FrameSource] = Registry(
    "source format",
    "ravenmem.sources",
    {fmt: f"ravenmem.ingest.{fmt}" for fmt in ("video", "tum", "folder")} | {"rosbag": "ravenmem.ros.bag"},
)
