"""A folder of images plus a pose file.

The pose file is `poses=FILE`, or `poses.csv` / `poses.txt` inside the folder. Two schemes, chosen
by whether the pose file has a `file` column (see poses.py for the layouts):

* Per-image rows (header with `file`/`filename`): each row gives the pose of the named image
  (name relative to the folder). Images without a row are skipped ("no pose row for image").
* A time-stamped track (no `file` column): each image gets a time and its pose is interpolated
  (or the nearest sample, `pose_match="nearest"`) from the track.

Image time, first rule that applies: the row's `t` column (per-image rows); with `fps`,
`start_time + i / fps` for the i-th image in name order (digit runs compared as numbers, so
frame_2 < frame_10); otherwise the file name's stem must be a number (`1305031229.528748.jpg`,
seconds), integers above 1e17, 1e14 or 1e11 being read as ns, us or ms (ROS exporters' names).
Frames come out in time order.

Depth (for maps): `depth=DIR`, a folder of depth images matching the colour images by file
stem (`000123.png` <-> `000123.png`), or else by the time in their names (nearest within
`depth_max_gap` s). 16-bit images are divided by `depth_scale` (units per metre, 1000 = mm by
default; TUM's is 5000), float images and `.npy` arrays are metres. The camera is
`intrinsics=` (a preset or fx,fy,cx,cy) and `camera_frame=` says what the poses are: `body`
(x forward, z up: a robot base or a level camera, the default) or `optical` (the camera's
own x right, y down, z forward frame, as SLAM systems and TUM write it).
"""

from __future__ import annotations

import bisect
import contextlib
import re
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

from ..errors import InputError
from ..types import Frame, Intrinsics, Pose
from .base import SOURCES, SourceConfig, SourceStats
from .common import (
    IMAGE_EXTS,
    check_flag,
    check_gap,
    check_intrinsics,
    check_positive,
    existing,
    parse_start_time,
    read_rgb,
)
from .depth import read_depth_file
from .identity import file_head, make_identity
from .poses import PoseTable, PoseTrack, check_match_mode, read_pose_table

SKIP_NO_ROW = "no pose row for image"
DEPTH_EXTS = (".png", ".tif", ".tiff", ".pgm", ".npy")


def natural_key(name: str) -> list[Any]:
    """Sort key comparing digit runs as numbers, so frame_2 sorts before frame_10."""
    return [(0, int(p), "") if p.isdigit() else (1, 0, p) for p in re.split(r"(\d+)", name) if p]


def time_from_name(name: str) -> float | None:
    """Seconds from a numeric file stem (ns/us/ms integers scaled by magnitude), else None."""
    stem = name.rsplit(".", 1)[0] if "." in name else name
    try:
        v = float(stem)
    except ValueError:
        return None
    if "." not in stem and "e" not in stem.lower():
        for limit, scale in ((1e17, 1e-9), (1e14, 1e-6), (1e11, 1e-3)):
            if v > limit:
                return v * scale
    return v


@dataclass
class FolderConfig(SourceConfig):
    """A folder of images (`folder:PATH`), posed from a pose file. poses: the file (default:
    one found beside the images); fps / start_time: frame times when the names carry none;
    pose_match `interpolate` or `nearest` (within max_gap s, 0.05 when not given); sort_poses:
    sort a pose file written out of order; depth: a folder of matching depth images
    (depth_scale units per metre for 16-bit ones, paired within depth_max_gap s by name or
    time); intrinsics: the depth camera's; camera_frame: the poses are of a `body` (x forward,
    z up) or of the camera's `optical` frame."""

    poses: str | Path | None = None
    fps: float | None = None
    start_time: float | str = 0.0
    pose_match: str = "interpolate"
    max_gap: float | None = None
    sort_poses: bool = False
    depth: str | Path | None = None
    depth_scale: float = 1000.0
    depth_max_gap: float = 0.02
    intrinsics: Intrinsics | str | None = None
    camera_frame: str = "body"

    kind: ClassVar[str] = "folder"

    def __post_init__(self) -> None:
        self.fps = check_positive("folder", "fps", self.fps)
        check_match_mode(self.pose_match)
        self.max_gap = check_gap("folder", "max_gap", self.max_gap)
        if self.max_gap is None and self.pose_match == "nearest":
            self.max_gap = 0.05
        check_flag("folder", "sort_poses", self.sort_poses)
        self.depth_scale = check_positive("folder", "depth_scale", self.depth_scale) or 0.0
        self.depth_max_gap = check_gap("folder", "depth_max_gap", self.depth_max_gap) or 0.0
        if self.camera_frame not in ("body", "optical"):
            raise InputError(f"folder: camera_frame must be 'body' or 'optical', got {self.camera_frame!r}")
        self.intrinsics = check_intrinsics(self.intrinsics)


class FolderSource:
    """Images in a folder (not recursive), posed from a pose file (options: `FolderConfig`)."""

    def __init__(self, path: str | Path | FolderConfig, **options: Any) -> None:
        cfg = self.config = FolderConfig.of(path, **options)
        self.root = existing(cfg.path, "image folder", want_dir=True)
        self.name = f"folder:{self.root.name}"
        self.stats = SourceStats()
        self.pose_match = check_match_mode(cfg.pose_match)
        self.max_gap = cfg.max_gap
        table = read_pose_table(self._pose_file(cfg.poses))
        names = [p.name for p in self.root.iterdir() if p.is_file() and p.suffix.lower() in IMAGE_EXTS]
        if not names:
            raise InputError(f"{self.root}: no images ({', '.join(IMAGE_EXTS)})")
        start = parse_start_time(cfg.start_time)
        self.rows: dict[str, int] | None = None
        self.table: PoseTable | None = None
        self.track: PoseTrack | None = None
        if table.files is not None:
            self.table = table
            self.rows = {}
            for i, f in enumerate(table.files):
                if f in self.rows:
                    raise InputError(f"{table.path} line {table.lines[i]}, column 'file': {f!r} listed twice")
                self.rows[f] = i
        else:
            self.track = PoseTrack.from_table(table, sort=cfg.sort_poses)
        self.items = self._timed(names, cfg.fps, start)
        self.depth_scale = cfg.depth_scale
        self.camera_extrinsic = cfg.camera_frame
        self.intrinsics: Intrinsics | None = cfg.intrinsics  # type: ignore[assignment]
        self.depth_files = self._match_depth(cfg.depth, cfg.depth_max_gap) if cfg.depth is not None else {}

    def _match_depth(self, folder: str | Path, max_gap: float) -> dict[str, Path]:
        """Colour image name -> its depth image: same stem, else nearest time in the names."""
        root = existing(folder, "depth folder", want_dir=True)
        files = [p for p in root.iterdir() if p.is_file() and p.suffix.lower() in DEPTH_EXTS]
        if not files:
            raise InputError(f"{root}: no depth images ({', '.join(DEPTH_EXTS)})")
        by_stem = {p.stem: p for p in files}
        timed = sorted((t, p) for p in files if (t := time_from_name(p.name)) is not None)
        ts = [t for t, _ in timed]
        out: dict[str, Path] = {}
        for name, _ in self.items:
            stem = name.rsplit(".", 1)[0]
            if stem in by_stem:
                out[name] = by_stem[stem]
                continue
            t = time_from_name(name)
            if t is None or not ts:
                continue
            i = bisect.bisect_left(ts, t)
            near = min((j for j in (i - 1, i) if 0 <= j < len(ts)), key=lambda j: abs(ts[j] - t))
            if abs(ts[near] - t) <= max_gap:
                out[name] = timed[near][1]
        if not out:
            raise InputError(f"{root}: no depth image matches a colour image by name or time")
        return out

    @property
    def frame_count(self) -> int:
        return len(self.items)

    def identity(self) -> str:
        """The folder's name, the names and sizes of its first 256 images in playback order,
        and the first image's first 64 KiB."""
        parts: list[bytes | str] = []
        for name, _ in self.items[:256]:
            try:
                size = (self.root / name).stat().st_size
            except OSError:
                size = -1
            parts.append(f"{name}\0{size}")
        with contextlib.suppress(OSError):
            parts.append(file_head(self.root / self.items[0][0], 1 << 16))
        return make_identity("folder", self.root.name, parts)

    def _pose_file(self, poses: str | Path | None) -> Path:
        if poses is not None:
            return existing(poses, "pose file", want_dir=False)
        for cand in ("poses.csv", "poses.txt"):
            if (self.root / cand).is_file():
                return self.root / cand
        raise InputError(f"{self.root}: no pose file; pass poses=FILE or put poses.csv in the folder")

    def _timed(self, names: list[str], fps: float | None, start: float) -> list[tuple[str, float]]:
        """(name, time) per image in playback order (time order; images without a pose row last)."""
        if self.table is not None and self.table.t is not None and self.rows is not None:
            t_col = self.table.t
            nan = float("nan")
            timed = [(n, float(t_col[self.rows[n]]) if n in self.rows else nan) for n in names]
        elif fps is not None:
            timed = [(n, start + i / fps) for i, n in enumerate(sorted(names, key=natural_key))]
        else:
            from_names = {n: time_from_name(n) for n in names}
            bad = sorted(n for n, t in from_names.items() if t is None)
            if bad:
                raise InputError(
                    f"{self.root / bad[0]}: cannot tell the image's time from its name; name images by "
                    "timestamp (e.g. 1305031229.528748.jpg), pass fps=..., or give the pose file t and file columns"
                )
            timed = [(n, t) for n, t in from_names.items() if t is not None]
        return sorted(
            timed, key=lambda it: (it[1] != it[1], it[1] if it[1] == it[1] else 0.0, natural_key(it[0]))
        )

    def _pose(self, name: str, t: float) -> Pose | str:
        if self.track is not None:
            return self.track.match(t, self.pose_match, self.max_gap)
        assert self.rows is not None and self.table is not None
        i = self.rows.get(name)
        if i is None:
            return SKIP_NO_ROW
        tb = self.table
        x, y, z = (float(v) for v in tb.xyz[i])
        if tb.quat is not None:
            return Pose.from_quaternion(x, y, z, *(float(v) for v in tb.quat[i]))
        return Pose(x, y, z, float(tb.yaw[i]) if tb.yaw is not None else 0.0)

    def __iter__(self) -> Iterator[Frame]:
        self.stats = SourceStats()
        for i, (name, t) in enumerate(self.items):
            self.stats.frames_seen += 1
            pose = self._pose(name, t)
            if isinstance(pose, str):
                self.stats.skip(pose)
                continue
            image = read_rgb(self.root / name)
            if isinstance(image, str):
                self.stats.skip(image)
                continue
            self.stats.raw_bytes += image.size
            self.stats.frames_yielded += 1
            dpath = self.depth_files.get(name)
            depth = read_depth_file(dpath, self.depth_scale) if dpath is not None else None
            yield Frame(
                image=image,
                t=t,
                pose=pose,
                source=str(self.root),
                index=i,
                path=str(self.root / name),
                depth=depth,
            )


@SOURCES.register("folder")
def _folder(spec: str | FolderConfig, **kwargs: Any) -> FolderSource:
    return FolderSource(FolderConfig.of(spec, **kwargs))
