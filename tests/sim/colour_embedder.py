"""A tiny deterministic embedder for tests: images -> share of strongly red / green / blue
pixels, texts -> the colour words they contain. Good enough to find coloured boxes."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

COLOURS = ("red", "green", "blue")


class ColourEmbedder:
    name = "test-colour"
    dim = 4

    def embed_images(self, images: Sequence[np.ndarray]) -> np.ndarray:
        out = []
        for im in images:
            a = np.asarray(im, np.float32)
            r, g, b = a[..., 0], a[..., 1], a[..., 2]
            shares = [
                np.mean((c > 150) & (c > 2 * o1) & (c > 2 * o2))
                for c, o1, o2 in ((r, g, b), (g, r, b), (b, r, g))
            ]
            v = np.array([*shares, 0.02], np.float32)
            out.append(v / np.linalg.norm(v))
        return np.stack(out)

    def embed_texts(self, texts: Sequence[str]) -> np.ndarray:
        out = []
        for t in texts:
            v = np.array([float(c in t.lower()) for c in COLOURS] + [0.02], np.float32)
            out.append(v / np.linalg.norm(v))
        return np.stack(out)
