"""Oracle perception: the simulator's ground-truth labels in place of an image embedder.

An upper bound for the demo. The keyframes, poses and times are the robot's own, and the
memory, its tools, the agent and the planner are the real ones; only perception is perfect:
a keyframe's vector says which kinds of object are in view and how large (label box pixels),
a text's vector names the object kind it mentions. Whatever SR remains below 100 % is lost by
memory selection, the agent or the planner, not by perception.

Vector layout: one dimension per object kind (sqrt of its largest box in pixels, so nearer
objects weigh more), one constant dimension (`REF`: a keyframe with a small object in a
corner scores lower than one filled with it), and one "other" dimension that only texts
naming no known kind use, so they match nothing.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..embed.base import EMBEDDERS
from ..errors import InputError
from ..memory import Memory, create
from ..sim.queries import match_kind
from ..types import Frame

REF = math.sqrt(1000.0)  # a box of 1000 px (about 40 x 25 at 320 x 240) scores 1 / sqrt(2)


class LabelEmbedder:
    """Texts -> the object kind they name; keyframes are embedded from labels by `embed_labels`
    (this embedder has no image model: `embed_images` refuses)."""

    def __init__(self, kinds: Sequence[str]) -> None:
        self.kinds = sorted(set(kinds))
        self._index = {k: i for i, k in enumerate(self.kinds)}

    @property
    def name(self) -> str:
        return "oracle-labels:" + ",".join(self.kinds)

    @property
    def dim(self) -> int:
        return len(self.kinds) + 2

    def embed_labels(self, labels: Mapping[str, float]) -> np.ndarray:
        """One keyframe: {kind: box pixels} -> a unit vector."""
        v = np.zeros(self.dim, np.float32)
        for kind, px in labels.items():
            if kind in self._index:
                i = self._index[kind]
                v[i] = max(v[i], math.sqrt(max(0.0, float(px))))
        v[-2] = REF
        return v / np.linalg.norm(v)

    def embed_images(self, images: Sequence[np.ndarray]) -> np.ndarray:
        raise InputError("oracle perception reads the simulator's labels, not pictures")

    def embed_texts(self, texts: Sequence[str]) -> np.ndarray:
        out = np.zeros((len(texts), self.dim), np.float32)
        for row, text in zip(out, texts):
            kind = match_kind(text, self.kinds)
            row[self._index[kind] if kind is not None else -1] = 1.0
        return out


def oracle_memory(
    folder: str | Path,
    mem: Memory,
    keyframe_px: Mapping[int, Mapping[int, int]],
    kind_of: Mapping[int, str],
) -> Memory:
    """A memory with `mem`'s keyframes (same ids order, poses, times, thumbnails) embedded by
    oracle perception from each keyframe's labels ({memory id: {object id: box pixels}})."""
    emb = LabelEmbedder(list(kind_of.values()))
    out = create(folder, embedder=emb, ocr=False, thumb_size=mem.thumb_size or 320)
    frames: list[Frame] = []
    vecs: list[np.ndarray] = []
    for rec in mem.all_records():
        labels: dict[str, float] = {}
        for oid, px in keyframe_px.get(rec.id, {}).items():
            kind = kind_of.get(int(oid))
            if kind is not None:
                labels[kind] = max(labels.get(kind, 0.0), float(px))
        image = mem.load_image(rec)
        frames.append(
            Frame(
                image=image if image is not None else np.zeros((2, 2, 3), np.uint8),
                t=rec.t,
                pose=rec.pose,
                source=rec.source,
                index=rec.frame_index,
            )
        )
        vecs.append(emb.embed_labels(labels))
    if frames:
        out.add_frames(frames, embeddings=np.stack(vecs))
    return out


@EMBEDDERS.register("oracle-labels")
def _factory(spec: str = "", **_: Any) -> LabelEmbedder:
    """`oracle-labels:KIND,KIND,...` (the name an oracle memory records), so that an oracle
    memory reopens in any process that imported this module."""
    return LabelEmbedder([k for k in spec.split(",") if k])
