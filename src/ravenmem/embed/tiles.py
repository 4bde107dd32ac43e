"""Tiling a frame so that small objects get enough pixels.

A 640x480 frame squeezed into a 224x224 classifier input turns a mug into a dozen pixels; the
same mug in a half-size tile is twice as large. Each layout is a fixed list of boxes in relative
coordinates (x0, y0, x1, y1); every box is resized to the same square input so that all tiles of
all images go through the network in one batch.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ..errors import InputError

Box = tuple[float, float, float, float]

FULL: Box = (0.0, 0.0, 1.0, 1.0)
QUADRANTS: list[Box] = [
    (0.0, 0.0, 0.5, 0.5),
    (0.5, 0.0, 1.0, 0.5),
    (0.0, 0.5, 0.5, 1.0),
    (0.5, 0.5, 1.0, 1.0),
]
CENTRE: Box = (0.25, 0.25, 0.75, 0.75)
# half-size windows on a quarter-size stride: the quadrants, the centre and the four edge midpoints
GRID9: list[Box] = [(x, y, x + 0.5, y + 0.5) for y in (0.0, 0.25, 0.5) for x in (0.0, 0.25, 0.5)]

LAYOUTS: dict[int, list[Box]] = {
    1: [FULL],
    5: [FULL, *QUADRANTS],
    6: [FULL, *QUADRANTS, CENTRE],
    10: [FULL, *GRID9],
}


def layout(n_tiles: int) -> list[Box]:
    """The boxes of a layout by its tile count (1, 5, 6 or 10)."""
    if n_tiles not in LAYOUTS:
        raise InputError(f"tiles={n_tiles}: choose one of {', '.join(map(str, sorted(LAYOUTS)))}")
    return LAYOUTS[n_tiles]


def check_image(image: np.ndarray, index: int = 0) -> np.ndarray:
    """Return `image` as a contiguous RGB uint8 (H, W, 3) array or raise InputError naming it."""
    arr = np.asarray(image)
    if arr.ndim != 3 or arr.shape[2] != 3 or arr.shape[0] < 2 or arr.shape[1] < 2:
        raise InputError(f"image {index}: expected an RGB array of shape (H, W, 3), got {arr.shape}")
    if arr.dtype != np.uint8:
        raise InputError(f"image {index}: expected dtype uint8, got {arr.dtype}")
    return np.ascontiguousarray(arr)


def tile_batch(images: Sequence[np.ndarray], boxes: Sequence[Box], size: int) -> np.ndarray:
    """Crop every box of every image and resize it to `size` x `size`.

    Returns (len(images) * len(boxes), 3, size, size) float32 in [0, 1], image-major (all tiles
    of image 0 first). Resizing is antialiased bilinear on float channels (Pillow's "F" mode),
    cropping first so that a tile never sees pixels outside its box: the same numbers, to 1e-5,
    as torch's `interpolate(..., mode="bilinear", antialias=True)` that built the memories
    before torch left the core install (tested), at a tenth of its time.
    """
    from PIL import Image

    out = np.empty((len(images) * len(boxes), 3, size, size), dtype=np.float32)
    for i, img in enumerate(images):
        arr = check_image(img, i)
        h, w = arr.shape[:2]
        channels = [Image.fromarray(arr[:, :, c].astype(np.float32) / 255.0) for c in range(3)]  # mode "F"
        for j, (x0, y0, x1, y1) in enumerate(boxes):
            left, top = round(x0 * w), round(y0 * h)
            crop = (left, top, max(round(x1 * w), left + 1), max(round(y1 * h), top + 1))
            for c, chan in enumerate(channels):
                out[i * len(boxes) + j, c] = np.asarray(
                    chan.crop(crop).resize((size, size), Image.Resampling.BILINEAR)
                )
    return np.clip(out, 0.0, 1.0, out=out)
