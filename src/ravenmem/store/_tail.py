"""The newest memories' exact vectors, kept in RAM by the local store.

Questions about a robot's world lean on its recent past: the latest mode (`last_seen`) scans
the newest thousand memories exactly on every question, and a place's newest views are scored
from the same stretch. Read from SQLite those scans cost a vector read each (1.3 ms for the
newest thousand at 1M memories); from RAM, a matrix product. The tail holds every stored
vector with an id above `after` (ids grow with insertion): `capacity` of them, in a buffer of
`budget` bytes that holds twice that (so that appends rarely move it): 32 MB keep the newest
10,922 memories at dim 384 and 3,640 at dim 1152.

It is loaded on the first exact search that it could answer and follows the store's own adds
(appended). Deletes need nothing: a search scores only the ids its filter accepts, from the
columns, which drop them. Like the index and the columns it is what this store held at open
plus its own writes.
"""

from __future__ import annotations

import numpy as np

TAIL_BYTES = 32 << 20


def capacity(dim: int, budget: int | None = None) -> int:
    """How many of the newest memories a tail of `budget` bytes (`TAIL_BYTES`) keeps."""
    return max(1, (TAIL_BYTES if budget is None else budget) // (8 * dim))


class Tail:
    def __init__(
        self, dim: int, after: int, ids: np.ndarray, vecs: np.ndarray, budget: int | None = None
    ) -> None:
        """`ids` (ascending) and their float32 `vecs`: every stored vector with an id above `after`."""
        self.dim, self.after = dim, after
        self.cap = capacity(dim, budget)
        self._ids = np.empty(2 * self.cap, np.int64)
        self._vecs = np.empty((2 * self.cap, dim), np.float32)
        self.n = 0
        self.append(ids, vecs)

    @property
    def ids(self) -> np.ndarray:
        return self._ids[: self.n]

    def covers(self, allowed: np.ndarray) -> bool:
        """Whether every id of `allowed` (sorted, non-empty) that is stored is held here."""
        return len(allowed) > 0 and int(allowed[0]) > self.after

    def scores(self, allowed: np.ndarray, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(ids, cosines) of the `allowed` ids held here (those no longer stored are left out)."""
        ids = self.ids
        lo = int(np.searchsorted(ids, allowed[0])) if len(allowed) else 0
        hi = lo + len(allowed)
        if len(allowed) and hi <= self.n and ids[lo] == allowed[0] and ids[hi - 1] == allowed[-1]:
            return ids[lo:hi], self._vecs[lo:hi] @ q  # a run of the held ids (a time window): no gather
        at = np.minimum(np.searchsorted(ids, allowed), max(self.n - 1, 0))
        held = at[ids[at] == allowed] if self.n else at[:0]
        return ids[held], self._vecs[held] @ q

    def append(self, ids: np.ndarray, vecs: np.ndarray) -> None:
        """Newly stored memories (ids above every held one); the oldest go beyond `cap`."""
        m = len(ids)
        if m >= self.cap:  # only the newest cap of them stay
            ids, vecs = ids[-self.cap :], vecs[-self.cap :]
            self.after, self.n, m = max(self.after, int(ids[0]) - 1), 0, self.cap
        if self.n + m > len(self._ids):  # make room: keep the newest cap - m, moved to the front
            keep = self.cap - m  # 0 < keep < n here
            self.after = max(self.after, int(self._ids[self.n - keep - 1]))  # the newest let go
            self._ids[:keep] = self._ids[self.n - keep : self.n]
            self._vecs[:keep] = self._vecs[self.n - keep : self.n]
            self.n = keep
        self._ids[self.n : self.n + m] = ids
        self._vecs[self.n : self.n + m] = vecs
        self.n += m
