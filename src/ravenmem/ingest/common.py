"""Small helpers shared by the file-based sources (path checks, pose-track arguments, images)."""

from __future__ import annotations

import math
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError

from ..errors import InputError
from ..types import Intrinsics
from .depth import parse_intrinsics
from .poses import PoseTrack, load_pose_track

IMAGE_EXTS = (".jpg", ".jpeg", ".png", ".bmp", ".webp", ".tif", ".tiff", ".ppm", ".pgm")

SKIP_MISSING_IMAGE = "missing image file"
SKIP_BAD_IMAGE = "unreadable image"


def existing(path: str | Path, what: str, want_dir: bool | None = None) -> Path:
    """Return the path, or raise InputError when it is missing or of the wrong kind."""
    p = Path(path).expanduser()
    if not p.exists():
        raise InputError(f"{p}: {what} not found")
    if want_dir is True and not p.is_dir():
        raise InputError(f"{p}: {what} must be a folder")
    if want_dir is False and p.is_dir():
        raise InputError(f"{p}: {what} must be a file, not a folder")
    return p


def pose_track_arg(poses: str | Path | PoseTrack, sort: bool = False) -> PoseTrack:
    """Accept a pose file path or an already built PoseTrack."""
    if isinstance(poses, PoseTrack):
        return poses
    return load_pose_track(existing(poses, "pose file", want_dir=False), sort=sort)


def parse_start_time(value: float | int | str) -> float:
    """Epoch seconds from a number, a numeric string or an ISO 8601 datetime (naive = UTC)."""
    if isinstance(value, (int, float)):
        v = float(value)
    else:
        s = value.strip()
        try:
            v = float(s)
        except ValueError:
            try:
                dt = datetime.fromisoformat(s.replace("Z", "+00:00"))
            except ValueError:
                raise InputError(
                    f"start time {value!r} is neither epoch seconds nor an ISO 8601 datetime"
                ) from None
            if dt.tzinfo is None:
                dt = dt.replace(tzinfo=timezone.utc)
            v = dt.timestamp()
    if not math.isfinite(v):
        raise InputError(f"start time {value!r} is not finite")
    return v


def pil_to_rgb(im: Image.Image) -> np.ndarray:
    """Writable RGB uint8 from any PIL image; 16/32-bit grey is scaled by its maximum to stay visible."""
    if im.mode in ("I;16", "I;16B", "I;16L", "I", "F"):
        a = np.asarray(im, dtype=np.float64)
        a = np.clip(a * (255.0 / max(float(np.nanmax(a)) if a.size else 0.0, 1.0)), 0, 255)
        return np.repeat(a.astype(np.uint8)[:, :, None], 3, axis=2)
    return np.array(im.convert("RGB"), dtype=np.uint8)  # a writable copy: callers may draw on it


def read_rgb(path: Path) -> np.ndarray | str:
    """Decode an image file to RGB uint8, or return the skip reason when it cannot be read."""
    try:
        with Image.open(path) as im:
            im.load()
            return pil_to_rgb(im)
    except FileNotFoundError:
        return SKIP_MISSING_IMAGE
    except (UnidentifiedImageError, OSError, ValueError, SyntaxError):
        return SKIP_BAD_IMAGE


def check_gap(source: str, name: str, v: float | None) -> float | None:
    """A time gap option: None (no limit) or finite seconds >= 0."""
    if v is None:
        return None
    _number(source, name, v)
    if v < 0:
        raise InputError(f"{source}: {name} must be >= 0 seconds, got {v!r}")
    return float(v)


def check_positive(source: str, name: str, v: float | None) -> float | None:
    """A rate or scale option: None (not given) or a finite number > 0."""
    if v is None:
        return None
    _number(source, name, v)
    if v <= 0:
        raise InputError(f"{source}: {name} must be > 0, got {v!r}")
    return float(v)


def _number(source: str, name: str, v: object) -> None:
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        raise InputError(f"{source}: {name} must be a finite number, got {v!r}")


def check_flag(source: str, name: str, v: object) -> bool:
    if not isinstance(v, bool):
        raise InputError(f"{source}: {name} must be true or false, got {v!r}")
    return v


def check_intrinsics(v: Intrinsics | str | None) -> Intrinsics | None:
    """Camera intrinsics: given, a preset name or 'fx,fy,cx,cy' (parsed), or None."""
    return parse_intrinsics(v) if isinstance(v, str) else v
