"""Depth images and the cameras that took them: decoding, and intrinsics from presets or text.

Depth is always handed on as float32 metres along the optical axis, NaN where the sensor had
no reading (`Frame.depth`). Encodings: 16-bit PNG/TIFF with a scale in units per metre (TUM:
5000; most ROS drivers and RealSense exports: 1000, i.e. millimetres), float images in metres,
`.npy` arrays in metres; ROS `16UC1` (mm) and `32FC1` (m) messages.

Intrinsics presets are the published pinhole values of the TUM RGB-D benchmark's Kinects
(its depth images are registered to the colour camera, so the colour intrinsics apply), and
the ROS OpenNI default that TUM recommends when undistortion is not wanted.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
from PIL import Image, UnidentifiedImageError

from ..errors import InputError
from ..types import Intrinsics

# fx, fy, cx, cy at 640x480 (TUM RGB-D "Intrinsic Camera Calibration of the Kinect").
PRESETS: dict[str, Intrinsics] = {
    "fr1": Intrinsics(517.3, 516.5, 318.6, 255.3, 640, 480),
    "fr2": Intrinsics(520.9, 521.0, 325.1, 249.7, 640, 480),
    "fr3": Intrinsics(535.4, 539.2, 320.1, 247.6, 640, 480),
    "kinect": Intrinsics(525.0, 525.0, 319.5, 239.5, 640, 480),  # ROS OpenNI default
}
_ALIASES = {
    "freiburg1": "fr1",
    "freiburg2": "fr2",
    "freiburg3": "fr3",
    "tum-fr1": "fr1",
    "tum-fr2": "fr2",
    "tum-fr3": "fr3",
    "ros-default": "kinect",
    "openni": "kinect",
}


def parse_intrinsics(text: str) -> Intrinsics:
    """A preset name (fr1, fr2, fr3, kinect) or 'fx,fy,cx,cy[,width,height]' in pixels."""
    key = text.strip().lower()
    key = _ALIASES.get(key, key)
    if key in PRESETS:
        return PRESETS[key]
    parts = [p for p in re.split(r"[,\s]+", key) if p]
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        raise InputError(
            f"intrinsics {text!r}: give fx,fy,cx,cy[,width,height] or a preset ({', '.join(PRESETS)})"
        ) from None
    if len(vals) not in (4, 6):
        raise InputError(f"intrinsics {text!r}: expected 4 or 6 numbers, got {len(vals)}")
    size = (int(vals[4]), int(vals[5])) if len(vals) == 6 else (0, 0)
    return Intrinsics(vals[0], vals[1], vals[2], vals[3], *size)


def preset_from_name(name: str) -> Intrinsics | None:
    """The TUM preset a sequence's folder name points at ('rgbd_dataset_freiburg2_desk' ->
    fr2, 'tum_fr1_rpy' -> fr1), else None."""
    m = re.search(r"(?:freiburg|fr)([123])(?![0-9])", name.lower())
    return PRESETS[f"fr{m.group(1)}"] if m else None


def camera_info_intrinsics(msg: Any) -> Intrinsics:
    """Intrinsics from a `sensor_msgs/CameraInfo` message: K = [fx 0 cx; 0 fy cy; 0 0 1]."""
    k = np.asarray(msg.k if hasattr(msg, "k") else msg.K, np.float64).reshape(-1)
    if k.size != 9:
        raise InputError(f"camera_info: K has {k.size} values, expected 9")
    return Intrinsics(float(k[0]), float(k[4]), float(k[2]), float(k[5]), int(msg.width), int(msg.height))


def to_metres(raw: np.ndarray, scale: float | None) -> np.ndarray:
    """Integer depth / `scale` (units per metre), float depth as metres; 0, negative and
    non-finite values become NaN."""
    a = np.asarray(raw)
    out = a.astype(np.float32)
    if np.issubdtype(a.dtype, np.integer) and scale:
        out /= np.float32(scale)
    out[~np.isfinite(out) | (out <= 0)] = np.nan
    return out


def read_depth_file(path: Path, scale: float) -> np.ndarray | None:
    """A depth image file as float32 metres (integer images divided by `scale`), None when it
    cannot be read."""
    try:
        if path.suffix.lower() == ".npy":
            raw = np.load(path, allow_pickle=False)
        else:
            with Image.open(path) as im:
                raw = np.asarray(im)
    except (OSError, ValueError, UnidentifiedImageError, SyntaxError):
        return None
    if raw.ndim != 2:
        return None
    return to_metres(raw, scale)


def decode_depth_message(msg: Any) -> np.ndarray | str:
    """Metres from a `sensor_msgs/Image` depth message (16UC1 / mono16 in mm, 32FC1 in m),
    or the reason it was skipped."""
    enc = str(msg.encoding).lower()
    kinds = {"16uc1": ("u2", 1000.0), "mono16": ("u2", 1000.0), "32fc1": ("f4", None)}
    if enc not in kinds:
        return f"unsupported depth encoding {msg.encoding!r}"
    dt, scale = kinds[enc]
    bpp = 2 if dt == "u2" else 4
    h, w, step = int(msg.height), int(msg.width), int(msg.step)
    data = np.asarray(msg.data, dtype=np.uint8).reshape(-1)
    if h <= 0 or w <= 0 or step < w * bpp or data.size < h * step:
        return "malformed depth message"
    rows = np.ascontiguousarray(data[: h * step].reshape(h, step)[:, : w * bpp])
    arr = rows.view((">" if msg.is_bigendian else "<") + dt).reshape(h, w)
    return to_metres(arr, scale)
