"""Shared test fixtures: a tiny deterministic embedder and paths to the real TUM data."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
TUM = REPO.parent / "shared" / "data" / "tum_fr1_rpy"

COLORS = {
    "red": (255, 0, 0),
    "green": (0, 255, 0),
    "blue": (0, 0, 255),
    "yellow": (255, 255, 0),
    "cyan": (0, 255, 255),
    "magenta": (255, 0, 255),
    "white": (255, 255, 255),
    "black": (0, 0, 0),
}


class ColorEmbedder:
    """Images -> their mean colour direction; texts -> the colour they name.

    Cheap and exact, so facade tests can check ranking, filters and fusion without a model.
    """

    name = "test-color"
    dim = 4

    def embed_images(self, images: Sequence[np.ndarray]) -> np.ndarray:
        out = []
        for im in images:
            m = im.reshape(-1, 3).astype(np.float32).mean(0) / 255.0
            out.append([m[0], m[1], m[2], 0.15])
        v = np.asarray(out, dtype=np.float32)
        return v / np.linalg.norm(v, axis=1, keepdims=True)

    def embed_texts(self, texts: Sequence[str]) -> np.ndarray:
        out = []
        for t in texts:
            c = next((COLORS[w] for w in t.lower().split() if w in COLORS), (0, 0, 0))
            out.append([c[0] / 255, c[1] / 255, c[2] / 255, 0.15])
        v = np.asarray(out, dtype=np.float32)
        return v / np.linalg.norm(v, axis=1, keepdims=True)


def solid(color: str, h: int = 48, w: int = 64) -> np.ndarray:
    img = np.zeros((h, w, 3), dtype=np.uint8)
    img[:] = COLORS[color]
    return img


@pytest.fixture
def color_embedder() -> ColorEmbedder:
    return ColorEmbedder()


@pytest.fixture
def tum_path() -> Path:
    if not (TUM / "rgb.txt").exists():
        pytest.skip(f"real TUM data not found at {TUM} (it lives in the workplace's shared/ folder)")
    return TUM
