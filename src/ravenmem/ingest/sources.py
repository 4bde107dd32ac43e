"""Open any recording by path: the format is detected from what the path is.

Detection order: a folder with `rgb.txt` is TUM RGB-D; a folder with `metadata.yaml`, `*.db3` or
`*.mcap` is a ROS 2 bag; a folder of images is an image folder; a `.mp4/.mkv/.avi/.mov/.webm/.m4v`
file is a video; a `.bag` (ROS 1), `.mcap` or `.db3` file is a ROS bag.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ..errors import InputError
from . import video
from .base import SOURCES, FrameSource, SourceConfig
from .common import IMAGE_EXTS

BAG_EXTS = (".bag", ".mcap", ".db3")


def detect_format(path: str | Path) -> tuple[str, Path]:
    """(format name, path to hand to it) for a recording path; InputError when nothing fits."""
    p = Path(path).expanduser()
    if not p.exists():
        raise InputError(f"{p}: no such file or folder")
    if p.is_dir():
        if (p / "rgb.txt").is_file():
            return "tum", p
        if (p / "metadata.yaml").is_file():
            return "rosbag", p
        stores = sorted(f for f in p.iterdir() if f.suffix in (".mcap", ".db3"))
        if len(stores) == 1:
            return "rosbag", stores[0]
        if stores:
            raise InputError(
                f"{p}: several bag files and no metadata.yaml; open one of them: {stores[0].name}, ..."
            )
        if any(f.suffix.lower() in IMAGE_EXTS for f in p.iterdir() if f.is_file()):
            return "folder", p
        raise InputError(
            f"{p}: cannot tell the format (no rgb.txt, metadata.yaml, bag files or images); pass format=..."
        )
    suffix = p.suffix.lower()
    if suffix in video.VIDEO_EXTS:
        return "video", p
    if suffix in BAG_EXTS:
        return "rosbag", p
    known = ", ".join(video.VIDEO_EXTS + BAG_EXTS)
    raise InputError(f"{p}: unknown file type {suffix or '(none)'!r}; expected one of {known} or a folder")


def open_source(path: str | Path | SourceConfig, format: str | None = None, **kwargs: Any) -> FrameSource:
    """Open a recording as a FrameSource; `format` (video/tum/folder/rosbag) skips detection.
    `kwargs` are the source's options (its config's fields, e.g. `TumConfig`), checked before
    any file is read; a source's config may be given instead of the path."""
    if isinstance(path, SourceConfig):
        if format is not None and format != path.kind:
            raise InputError(f"a {path.kind} config cannot open a {format} source")
        return SOURCES.get(path.kind)(path, **kwargs)
    if format is None:
        format, p = detect_format(path)
    else:
        if format not in SOURCES.names():
            raise InputError(f"unknown source format {format!r}; choose one of: {', '.join(SOURCES.names())}")
        p = Path(path).expanduser()
    return SOURCES.create(f"{format}:{p}", **kwargs)
