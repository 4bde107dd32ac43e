"""Tiling a frame so that small objects get enough pixels.

A 640x480 frame squeezed into a 224x224 classifier input turns a mug into a dozen pixels; the
same mug in a half-size tile is twice as large. Each layout is a fixed list of boxes in relative
coordinates (x0, y0, x1, y1); every box is resized to the same square input so that all tiles of
all images go through the network in one batch.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np

from ..errors import InputError

if TYPE_CHECKING:
    import torch

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


def tile_batch(images: Sequence[np.ndarray], boxes: Sequence[Box], size: int) -> torch.Tensor:
    """Crop every box of every image and resize it to `size` x `size`.

    Returns (len(images) * len(boxes), 3, size, size) float32 in [0, 1], image-major (all tiles
    of image 0 first). Resizing is antialiased so that downscaled tiles do not alias. torch is
    imported here, not at module level: `layout` and `check_image` serve callers that never embed.
    """
    import torch
    import torch.nn.functional as F

    out = torch.empty((len(images) * len(boxes), 3, size, size), dtype=torch.float32)
    for i, img in enumerate(images):
        arr = check_image(img, i)
        if not arr.flags.writeable:  # torch.from_numpy warns on read-only arrays (e.g. from PIL)
            arr = arr.copy()
        h, w = arr.shape[:2]
        full = torch.from_numpy(arr).permute(2, 0, 1).unsqueeze(0).float().div_(255.0)
        for j, (x0, y0, x1, y1) in enumerate(boxes):
            crop = full[
                :,
                :,
                round(y0 * h) : max(round(y1 * h), round(y0 * h) + 1),
                round(x0 * w) : max(round(x1 * w), round(x0 * w) + 1),
            ]
            out[i * len(boxes) + j] = F.interpolate(
                crop, size=(size, size), mode="bilinear", antialias=True, align_corners=False
            )[0]
    return out.clamp_(0.0, 1.0)
