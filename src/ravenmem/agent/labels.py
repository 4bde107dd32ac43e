"""Words for what a memory's picture shows, for a model that cannot see pictures.

A text-only model gets each memory as text (time, pose, score, OCR text) plus a few labels: the
names of the label vocabulary nearest to the memory's stored embedding, both embedded by the
memory's own embedder. With the offline default the vocabulary is the ImageNet class list of
its classifier and the space is the one its images were embedded into, so the labels are the
offline embedder's own top classes for the frame; any embedder with a text side works the same
way. No image is decoded and no image model is loaded: only the stored vectors are read.
"""

from __future__ import annotations

import threading
from collections.abc import Sequence

import numpy as np

from ..memory.protocol import MemoryLike
from ..types import MemoryRecord

TOP_LABELS = 3
_BANKS: dict[tuple[str, tuple[str, ...]], np.ndarray] = {}  # (embedder name, vocabulary) -> vectors
_LOCK = threading.Lock()


def default_vocabulary() -> list[str]:
    """The offline embedder's label names (the first synonym of each ImageNet class)."""
    try:
        from ..embed.offline import label_names as class_names
    except ImportError:  # an install without the offline embedder's files
        return []
    return list(dict.fromkeys(n.split(",")[0].strip() for n in class_names()))


class FrameLabels:
    """`labels(records) -> {id: [label, ...]}` for one memory (vectors of the vocabulary are
    computed once per embedder and process)."""

    def __init__(self, mem: MemoryLike, vocabulary: Sequence[str] | None = None, k: int = TOP_LABELS) -> None:
        self.mem = mem
        self.vocabulary = list(vocabulary) if vocabulary is not None else default_vocabulary()
        self.k = k

    def _bank(self) -> np.ndarray:
        key = (self.mem.embedder.name, tuple(self.vocabulary))
        with _LOCK:
            bank = _BANKS.get(key)
        if bank is None:
            bank = np.asarray(self.mem.embedder.embed_texts(self.vocabulary), dtype=np.float32)
            with _LOCK:
                _BANKS[key] = bank
        return bank

    def __call__(self, records: Sequence[MemoryRecord]) -> dict[int, list[str]]:
        stored = getattr(self.mem, "stored", None)
        if not records or not self.vocabulary or stored is None:
            return {}
        recs = [r for r in stored([r.id for r in records], with_embeddings=True) if r.embedding is not None]
        if not recs:
            return {}
        bank = self._bank()
        vecs = np.stack([np.asarray(r.embedding, dtype=np.float32) for r in recs])
        if vecs.shape[1] != bank.shape[1]:
            return {}
        scores = vecs @ bank.T
        top = np.argsort(-scores, axis=1)[:, : self.k]
        return {r.id: [self.vocabulary[j] for j in row] for r, row in zip(recs, top)}
