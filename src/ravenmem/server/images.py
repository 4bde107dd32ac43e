"""Uploaded pictures in, bounded: JPEG or PNG bytes -> an RGB uint8 array, or one-line error."""

from __future__ import annotations

import base64
import binascii
import io
import re
import warnings

import numpy as np
from PIL import Image, UnidentifiedImageError

from ..errors import InputError

FORMATS = ("JPEG", "PNG")
_DATA_URL = re.compile(r"^data:image/[a-z.+-]+;base64,", re.IGNORECASE)


def decode_image(data: bytes, max_pixels: int, what: str = "image") -> np.ndarray:
    """Decode a JPEG/PNG upload; the pixel count is checked from the header, before decoding,
    so a small file that inflates to gigabytes is refused without being inflated."""
    if not data:
        raise InputError(f"{what}: empty upload")
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("error", Image.DecompressionBombWarning)
            with Image.open(io.BytesIO(data)) as im:
                if im.format not in FORMATS:
                    raise InputError(
                        f"{what}: {im.format or 'unknown'} images are not taken; send JPEG or PNG"
                    )
                w, h = im.size
                if w * h > max_pixels:
                    raise InputError(f"{what}: {w}x{h} pixels is more than the limit of {max_pixels}")
                return np.asarray(im.convert("RGB"), dtype=np.uint8)
    except InputError:
        raise
    except (UnidentifiedImageError, OSError, ValueError, Image.DecompressionBombError, Warning) as e:
        raise InputError(f"{what}: not a readable JPEG or PNG image ({type(e).__name__})") from None


def decode_base64_image(text: str, max_pixels: int, what: str = "image") -> np.ndarray:
    """An image sent inside JSON: base64, optionally as a `data:image/...;base64,` URL."""
    body = _DATA_URL.sub("", text.strip(), count=1)
    try:
        data = base64.b64decode(body, validate=True)
    except (binascii.Error, ValueError):
        raise InputError(f"{what}: not valid base64") from None
    return decode_image(data, max_pixels, what)


def decode_depth(data: bytes, max_pixels: int, scale: float, what: str = "depth") -> np.ndarray:
    """A depth upload as float32 metres: a single-channel PNG (integers divided by `scale`, units
    per metre: 1000 for millimetres) or a `.npy` array (metres); 0 and invalid readings are NaN."""
    from ..ingest.depth import to_metres

    if not data:
        raise InputError(f"{what}: empty upload")
    if not scale > 0:
        raise InputError(f"{what}: depth_scale must be > 0, got {scale}")
    try:
        if data.startswith(b"\x93NUMPY"):
            raw = np.load(io.BytesIO(data), allow_pickle=False)
        else:
            with warnings.catch_warnings():
                warnings.simplefilter("error", Image.DecompressionBombWarning)
                with Image.open(io.BytesIO(data)) as im:
                    if im.format != "PNG":
                        raise InputError(f"{what}: send a 16-bit PNG or a .npy array, not {im.format}")
                    w, h = im.size
                    if w * h > max_pixels:
                        raise InputError(f"{what}: {w}x{h} pixels is more than the limit of {max_pixels}")
                    raw = np.asarray(im)
    except InputError:
        raise
    except (UnidentifiedImageError, OSError, ValueError, Image.DecompressionBombError, Warning) as e:
        raise InputError(f"{what}: not a readable depth PNG or .npy array ({type(e).__name__})") from None
    if (
        raw.ndim != 2
        or raw.size > max_pixels
        or not (np.issubdtype(raw.dtype, np.integer) or np.issubdtype(raw.dtype, np.floating))
    ):
        raise InputError(f"{what}: expected one channel of depth, got shape {raw.shape} {raw.dtype}")
    return to_metres(raw, scale)
