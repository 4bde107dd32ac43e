"""Uploaded pictures in, bounded: JPEG or PNG bytes -> an RGB uint8 array, or one-line error.

Two bounds keep what pictures cost in RAM: the pixels of one picture (`max_pixels`, read from
the header before anything is decoded: 413 past it), and the RAM all the pictures being decoded
and used at once may hold (`DecodeGate`, sized to the machine's memory: a request that would go
past it waits a few seconds for others to finish, then is answered 503 with Retry-After).
A picture's share is given back when its array is freed (the search or the add is done).
"""

from __future__ import annotations

import base64
import binascii
import io
import os
import re
import threading
import warnings
import weakref

import numpy as np
from PIL import Image, UnidentifiedImageError

from ..errors import InputError
from .live import BusyError

FORMATS = ("JPEG", "PNG")
_DATA_URL = re.compile(r"^data:image/[a-z.+-]+;base64,", re.IGNORECASE)
BYTES_PER_PIXEL = 16  # decoding (PIL's 4 bytes a pixel, the 3-byte array) and the embedder's float copy
GATE_WAIT_S = 5.0  # how long a picture waits for RAM before the request is answered 503


class TooLargeError(InputError):
    """An upload bigger than a per-request limit (pixels of a picture); HTTP 413."""


def ram_bytes() -> int:
    """This machine's physical memory (16 GiB when the OS does not say)."""
    try:
        return int(os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES"))
    except (ValueError, OSError, AttributeError):  # pragma: no cover - not POSIX
        return 16 << 30


def default_budget() -> int:
    """RAM decoded pictures may hold at once: an eighth of the machine's, from 256 MiB to 2 GiB."""
    return int(min(max(ram_bytes() // 8, 256 << 20), 2 << 30))


class DecodeGate:
    """A budget of bytes for the pictures being decoded and used at once (see the module
    docstring): `admit(w, h)` before decoding, `hold(array, n)` gives the share back when the
    array is freed. Thread-safe."""

    def __init__(self, budget: int | None = None, wait: float = GATE_WAIT_S) -> None:
        self.budget = default_budget() if budget is None else int(budget)
        self.wait = wait
        self.used = 0
        self._cv = threading.Condition()

    def admit(self, w: int, h: int, what: str) -> int:
        """Reserve the RAM of a w x h picture; 413 when it alone is past the budget, 503 when
        the others being decoded leave no room within `wait` seconds. Returns the bytes taken."""
        n = w * h * BYTES_PER_PIXEL
        if n > self.budget:
            raise TooLargeError(
                f"{what}: {w}x{h} pixels needs more memory than this service gives one picture"
            )
        with self._cv:
            if not self._cv.wait_for(lambda: self.used + n <= self.budget, timeout=self.wait):
                raise BusyError(f"{what}: the service is decoding other large pictures; retry in a moment")
            self.used += n
        return n

    def release(self, n: int) -> None:
        with self._cv:
            self.used = max(0, self.used - n)
            self._cv.notify_all()

    def hold(self, array: np.ndarray, n: int) -> np.ndarray:
        """`array`, whose `n` reserved bytes are given back when it is freed."""
        weakref.finalize(array, self.release, n)
        return array


def decode_failure(e: Exception, what: str, max_pixels: int, kind: str) -> Exception:
    """The one error a failed decode of an upload gives: our own refusals as they are, a picture
    past the pixel limit 413 (`TooLargeError`), anything the decoder could not read one line."""
    if isinstance(e, InputError):
        return e
    if isinstance(e, (Image.DecompressionBombError, Image.DecompressionBombWarning)):
        return TooLargeError(f"{what}: more pixels than the limit of {max_pixels}")
    if isinstance(e, (UnidentifiedImageError, OSError, ValueError, Warning)):
        return InputError(f"{what}: not a readable {kind} ({type(e).__name__})")
    return e


_UNGATED = DecodeGate(budget=1 << 62)  # the Python API's default: only max_pixels bounds it


def decode_image(
    data: bytes, max_pixels: int, what: str = "image", gate: DecodeGate | None = None
) -> np.ndarray:
    """Decode a JPEG/PNG upload; the pixel count is checked from the header, before decoding,
    so a small file that inflates to gigabytes is refused without being inflated (413), and
    `gate` bounds what all pictures decoded at once hold (503)."""
    gate = gate or _UNGATED
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
                    raise TooLargeError(f"{what}: {w}x{h} pixels is more than the limit of {max_pixels}")
                n = gate.admit(w, h, what)
                try:
                    arr = np.asarray(im.convert("RGB"), dtype=np.uint8)
                except BaseException:
                    gate.release(n)
                    raise
                return gate.hold(arr, n)
    except Exception as e:
        raise decode_failure(e, what, max_pixels, "JPEG or PNG image") from None


def decode_base64_image(
    text: str, max_pixels: int, what: str = "image", gate: DecodeGate | None = None
) -> np.ndarray:
    """An image sent inside JSON: base64, optionally as a `data:image/...;base64,` URL."""
    body = _DATA_URL.sub("", text.strip(), count=1)
    try:
        data = base64.b64decode(body, validate=True)
    except (binascii.Error, ValueError):
        raise InputError(f"{what}: not valid base64") from None
    return decode_image(data, max_pixels, what, gate)


def _load_npy(data: bytes, max_pixels: int, what: str) -> np.ndarray:
    """A .npy upload, its header read and bounded first: a few bytes may claim 10^10 cells,
    which `np.load` would allocate before finding the data is not there (HTTP 413)."""
    f = io.BytesIO(data)
    version = np.lib.format.read_magic(f)
    if version == (1, 0):
        shape, _, dtype = np.lib.format.read_array_header_1_0(f)
    elif version in ((2, 0), (3, 0)):
        shape, _, dtype = np.lib.format.read_array_header_2_0(f)
    else:
        raise InputError(f"{what}: .npy format version {version} is not supported")
    cells = 1
    for n in shape:
        cells *= int(n)
    if cells > max_pixels:
        raise TooLargeError(f"{what}: a .npy array of {cells} cells is more than the limit of {max_pixels}")
    if cells * dtype.itemsize > len(data):
        raise InputError(f"{what}: the .npy header claims {cells} cells, the upload holds fewer")
    return np.load(io.BytesIO(data), allow_pickle=False)


def decode_depth(data: bytes, max_pixels: int, scale: float, what: str = "depth") -> np.ndarray:
    """A depth upload as float32 metres: a single-channel PNG (integers divided by `scale`, units
    per metre: 1000 for millimetres) or a `.npy` array (metres); 0 and invalid readings are NaN."""
    from ..ingest.depth import to_metres

    if not data:
        raise InputError(f"{what}: empty upload")
    if not scale > 0:
        raise InputError(f"{what}: depth_scale must be > 0, got {scale}")
    if not scale <= 1e6:
        raise InputError(f"{what}: depth_scale must be at most 1e6 units per metre, got {scale}")
    try:
        if data.startswith(b"\x93NUMPY"):
            raw = _load_npy(data, max_pixels, what)
        else:
            with warnings.catch_warnings():
                warnings.simplefilter("error", Image.DecompressionBombWarning)
                with Image.open(io.BytesIO(data)) as im:
                    if im.format != "PNG":
                        raise InputError(f"{what}: send a 16-bit PNG or a .npy array, not {im.format}")
                    w, h = im.size
                    if w * h > max_pixels:
                        raise TooLargeError(f"{what}: {w}x{h} pixels is more than the limit of {max_pixels}")
                    raw = np.asarray(im)
    except Exception as e:
        raise decode_failure(e, what, max_pixels, "depth PNG or .npy array") from None
    if (
        raw.ndim != 2
        or raw.size > max_pixels
        or not (np.issubdtype(raw.dtype, np.integer) or np.issubdtype(raw.dtype, np.floating))
    ):
        raise InputError(f"{what}: expected one channel of depth, got shape {raw.shape} {raw.dtype}")
    return to_metres(raw, scale)
