"""Image files in and out, with errors that name the file."""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
from PIL import Image, UnidentifiedImageError

from .errors import InputError
from .fsio import atomic_open


def read_image(path: str | os.PathLike[str]) -> np.ndarray:
    """Read an image file as RGB uint8 (H, W, 3).

    Any failure is one `InputError` naming the file: a missing or unreadable file, bytes that
    are not an image, a truncated or corrupt one (decoders raise many kinds of exceptions), or
    a decompression bomb (more pixels than Pillow's `Image.MAX_IMAGE_PIXELS` guard allows).
    """
    p = Path(path)
    if not p.exists():
        raise InputError(f"image file {p} does not exist")
    if not p.is_file():
        raise InputError(f"image file {p} is not a file")
    try:
        with Image.open(p) as im:
            return np.asarray(im.convert("RGB"), dtype=np.uint8)
    except Image.DecompressionBombError as e:
        raise InputError(f"image file {p} is too large to decode safely ({_first_line(e)})") from None
    except UnidentifiedImageError:
        raise InputError(f"image file {p} cannot be read: not an image Pillow knows") from None
    except Exception as e:  # decoders raise OSError, ValueError, SyntaxError, struct.error, ...
        raise InputError(f"image file {p} cannot be read: {_first_line(e)}") from None


def _first_line(e: BaseException) -> str:
    text = str(e).strip().splitlines()
    return text[0] if text else type(e).__name__


def resize_max_side(image: np.ndarray, max_side: int) -> Image.Image:
    im = Image.fromarray(image)
    if max_side > 0 and max(im.size) > max_side:
        s = max_side / max(im.size)
        im = im.resize((max(1, round(im.width * s)), max(1, round(im.height * s))), Image.Resampling.BILINEAR)
    return im


def write_jpeg(path: Path, image: np.ndarray, max_side: int = 0, quality: int = 85) -> None:
    """Write a JPEG crash-safely (`fsio.atomic_open`), shrunk so its longer side is <= max_side."""
    with atomic_open(path) as f:
        resize_max_side(image, max_side).save(f, format="JPEG", quality=quality)
