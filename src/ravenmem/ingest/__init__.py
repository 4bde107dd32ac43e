"""Sources (video + pose track, TUM RGB-D folder, image folder, ROS bags / MCAP), pose tracks,
keyframe selection and the ingest pipeline."""

from __future__ import annotations

from .base import SOURCES, FrameSource, SourceStats

__all__ = ["SOURCES", "FrameSource", "SourceStats", "open_source"]


def open_source(path: str, format: str | None = None, **kwargs: object) -> FrameSource:
    """Open a recording (format detected from the path when not given); see `sources.open_source`."""
    from .sources import open_source as _open

    return _open(path, format, **kwargs)
