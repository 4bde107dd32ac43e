"""The tests' embedder for pictures of a world (the simulators' coloured boxes): it really looks
at the pictures, the share of strongly red, green and blue pixels, and reads texts by the colour
words they hold. Registered as `test-boxes`, so `--embedder test-boxes` reaches it in-process.

A text naming no colour gets a dimension of its own that no picture has, so it matches nothing
(the offline reasoner's decoys score 0, as things that are not there should). Solid test
pictures use `tests.conftest.ColorEmbedder` instead (exact colours, not shares)."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ravenmem.embed.base import EMBEDDERS

COLOURS = ("red", "green", "blue")
REF = 0.05  # a box filling 0.25 % of the picture scores 1/sqrt(2)


class BoxEmbedder:
    name = "test-boxes"
    dim = 5

    def embed_images(self, images: Sequence[np.ndarray]) -> np.ndarray:
        out = []
        for im in images:
            a = np.asarray(im, np.float32)
            r, g, b = a[..., 0], a[..., 1], a[..., 2]
            shares = [
                float(np.mean((c > 140) & (c > 2 * o1) & (c > 2 * o2)))
                for c, o1, o2 in ((r, g, b), (g, r, b), (b, r, g))
            ]
            v = np.array([*np.sqrt(shares), REF, 0.0], np.float32)
            out.append(v / np.linalg.norm(v))
        return np.stack(out)

    def embed_texts(self, texts: Sequence[str]) -> np.ndarray:
        out = np.zeros((len(texts), self.dim), np.float32)
        for row, t in zip(out, texts):
            words = t.lower().replace(".", " ").split()
            hot = [i for i, c in enumerate(COLOURS) if c in words]
            row[hot if hot else [4]] = 1.0
            row /= np.linalg.norm(row)
        return out


@EMBEDDERS.register("test-boxes")
def _boxes(spec: str = "", **_: object) -> BoxEmbedder:
    return BoxEmbedder()
