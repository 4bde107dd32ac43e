"""The source axis: anything that yields timestamped, posed RGB frames, streaming.

A source must never load a whole recording into RAM: it yields frames one at a time.
It counts what it had to drop (unreadable frames, frames outside the pose track) in
`stats` so that `ravenmem ingest` and `info` can report them instead of guessing, and puts
what the user must hear about (a video that ended early) in `stats.warnings`.

Each built-in source takes a typed config (`TumConfig`, `FolderConfig`, `VideoConfig`,
`RosbagConfig`, all a `SourceConfig`), checked when it is built: a wrong value is a one-line
error before any file is read, and an option the source does not have is named with the ones
it has. The registry's `name:spec` string (`tum:PATH`) is the config's path; keyword
options (from Python, the CLI's flags) are its other fields.

Two optional members, which every built-in source has: `identity()`, the recording's identity
independent of its path (see `ingest.identity`; ingest uses it to skip frames already stored),
and `frame_count`, the number of frames the recording says it holds (None when it cannot tell
cheaply), for the progress bar's total and ETA.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any, ClassVar, Protocol, TypeVar, runtime_checkable

from ..errors import InputError
from ..registry import Registry
from ..types import Frame

C = TypeVar("C", bound="SourceConfig")


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


@dataclass
class SourceConfig:
    """What every source's config has: the recording's `path` (see the module docstring).
    Subclasses add their options as fields and check them in `__post_init__`."""

    path: Path

    kind: ClassVar[str] = "source"

    @classmethod
    def of(cls: type[C], path: str | Path | SourceConfig, **options: Any) -> C:
        """The config for `path` (or a config, with `options` changed) and keyword options; an
        option this source does not have is a one-line error that lists the ones it has."""
        names = [f.name for f in fields(cls) if f.name != "path"]
        unknown = sorted(set(options) - set(names))
        if unknown:
            raise InputError(
                f"{cls.kind} source has no option {', '.join(unknown)}; options: {', '.join(names)}"
            )
        if isinstance(path, cls):
            return replace(path, **options) if options else path
        if isinstance(path, SourceConfig):
            raise InputError(f"a {path.kind} config cannot open a {cls.kind} source")
        return cls(Path(path).expanduser(), **options)


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
