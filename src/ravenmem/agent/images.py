"""The pictures sent to a model: only bytes that decode as an image, only files inside the memory.

A stored thumbnail is a JPEG already, so it is sent byte for byte when it fits `max_side`
(0 = as stored); otherwise, and for arrays, it is decoded, shrunk and re-encoded. Nothing is
ever enlarged: the stored thumbnail size bounds what a model can see.
"""

from __future__ import annotations

import base64
import io
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
from PIL import Image, UnidentifiedImageError

from ..imageio import resize_max_side
from ..types import MemoryRecord

if TYPE_CHECKING:
    from ..memory.protocol import MemoryLike

MAX_FILE_BYTES = 32 * 1024 * 1024  # a memory's thumbnail is ~20 KB; anything this big is not one
MAX_PIXELS = 40_000_000  # refuse decompression bombs before decoding them
JPEG_QUALITY = 85


def jpeg_of_bytes(data: bytes, max_side: int = 0, quality: int = JPEG_QUALITY) -> bytes | None:
    """`data` as a JPEG no larger than `max_side`, or None when it does not decode as an image."""
    try:
        with Image.open(io.BytesIO(data)) as im:
            w, h = im.size
            if w * h > MAX_PIXELS:
                return None
            im.load()
            fits = max_side <= 0 or max(w, h) <= max_side
            if im.format == "JPEG" and im.mode in ("RGB", "L") and fits:
                return data
            arr = np.asarray(im.convert("RGB"), dtype=np.uint8)
    except (UnidentifiedImageError, OSError, ValueError, Image.DecompressionBombError, SyntaxError):
        return None
    return jpeg_of_array(arr, max_side, quality)


def jpeg_of_array(image: np.ndarray, max_side: int = 0, quality: int = JPEG_QUALITY) -> bytes:
    """An RGB uint8 array as JPEG bytes, shrunk so its longer side is at most `max_side`."""
    buf = io.BytesIO()
    resize_max_side(np.ascontiguousarray(image), max_side).save(buf, format="JPEG", quality=quality)
    return buf.getvalue()


def data_url(jpeg: bytes) -> str:
    return "data:image/jpeg;base64," + base64.b64encode(jpeg).decode("ascii")


def inside(path: Path, folder: Path) -> bool:
    """True when `path` (links resolved) lies inside `folder`."""
    try:
        return path.resolve().is_relative_to(folder.resolve())
    except (OSError, RuntimeError):
        return False


def record_jpeg(mem: MemoryLike, rec: MemoryRecord, max_side: int = 0) -> bytes | None:
    """A memory's picture as JPEG bytes, or None: no picture, a file outside the memory folder,
    a file too large, or bytes that do not decode as an image."""
    p = mem.image_file(rec)
    if p is None or not inside(Path(p), Path(mem.path)):
        return None
    try:
        with open(p, "rb") as f:
            data = f.read(MAX_FILE_BYTES + 1)
    except OSError:
        return None
    if len(data) > MAX_FILE_BYTES:
        return None
    return jpeg_of_bytes(data, max_side)
