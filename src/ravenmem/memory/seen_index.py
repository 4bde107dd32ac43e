"""What the latest mode (`ravenmem.memory.changes`) reads of a memory once, not per question.

`last_seen` needs two facts about the memory as a whole besides the question's own searches:
a typical memory's score (the median over a sample spread evenly over the memory) and the
robot's usual time between keyframes. Both were read afresh for every question, through the
store's full statistics (an aggregate over every row: a third of a second at a million
memories) and a few hundred single reads. Here they are computed once per memory state and kept
beside the memory object: the sample's embeddings (64 x dim floats) and the spacing. The state
is the store's count and the memory object's own writes, so an add, a forget or a consolidation
computes them again (an open store sees what it held when opened and its own writes since: a
reader sees another process's writes when it opens the memory again). The state is read
without listing the ids: that list cost 0.7 ms of a 20 ms question at a million memories.
"""

from __future__ import annotations

import threading
import weakref
from dataclasses import dataclass

import numpy as np

from .core import Core

__all__ = ["SeenIndex", "seen_index"]


@dataclass(frozen=True)
class SeenIndex:
    """The whole-memory facts of one memory state (see the module docstring)."""

    key: tuple[int, int]  # (store count, the memory object's writes)
    sample: np.ndarray  # (n, dim) embeddings of memories spread evenly over the memory
    spacing: float  # mean seconds between a memory and the next one stored, breaks left out

    def floor(self, q: np.ndarray) -> float:
        """A typical memory's score for the query vector `q`: the median over the sample."""
        return float(np.median(self.sample @ q)) if len(self.sample) else 0.0


_CACHE: weakref.WeakKeyDictionary[Core, SeenIndex] = weakref.WeakKeyDictionary()
_LOCK = threading.Lock()


def seen_index(mem: Core, n: int = 64) -> SeenIndex:
    """The memory's SeenIndex for its current state, computed when the state changed."""
    key = (mem.store.count(), mem.writes)
    with _LOCK:
        got = _CACHE.get(mem)
    if got is not None and got.key == key and len(got.sample) == min(n, key[0]):
        return got
    ids = mem.store.select()  # every stored id, ascending: ids grow with insertion
    made = SeenIndex((len(ids), key[1]), _sample(mem, ids, n), _spacing(mem, ids))
    with _LOCK:
        _CACHE[mem] = made
    return made


def _spread(ids: np.ndarray, n: int) -> np.ndarray:
    """Positions of about n ids spread evenly over `ids` (first and last included)."""
    if len(ids) == 0:
        return np.zeros(0, np.int64)
    return np.unique(np.linspace(0, len(ids) - 1, max(1, min(n, len(ids)))).round().astype(np.int64))


def _sample(mem: Core, ids: np.ndarray, n: int) -> np.ndarray:
    recs = mem.stored([int(i) for i in ids[_spread(ids, n)]], with_embeddings=True)
    rows = [np.asarray(r.embedding, np.float32) for r in recs if r.embedding is not None]
    return np.stack(rows) if rows else np.zeros((0, mem.dim), np.float32)


def _spacing(mem: Core, ids: np.ndarray, n: int = 64) -> float:
    """The robot's usual time between keyframes while recording: the mean time between a memory
    and the next one stored, over pairs spread over the memory, not counting breaks (gaps over
    10 times the median: the robot was off or elsewhere). The mean, not the median: keyframes
    come fast while turning and slowly while driving."""
    if len(ids) < 2:
        return 1.0
    first = _spread(ids[:-1], n)
    pairs = [(int(ids[p]), int(ids[p + 1])) for p in first]
    times = {r.id: r.t for r in mem.stored(sorted({i for pair in pairs for i in pair}))}
    diffs = np.array(
        [times[b] - times[a] for a, b in pairs if a in times and b in times and times[b] > times[a]]
    )
    if diffs.size == 0:
        return 1.0
    return float(diffs[diffs <= 10.0 * np.median(diffs)].mean())
