"""Where each IVF list's memories were taken: a bounding box per list, so that a search inside a
disc with a score floor tests the positions of the few lists that can matter, not of every
memory in its time range.

A list gathers memories that look alike, and on a robot those are mostly taken in one part of
the map: of the 187 lists that could hold a memory above a sighting threshold at 1M patrol
memories, 15 (25k of 320k memories) have a box that meets a place's 4.5 m disc. The latest
mode's search for a place's later sightings tested the disc against the 500k positions of its
time range (0.9 ms) to learn which memories it accepts; those lists' 25k memories say it too.

A box is read the first time a search asks about its list (from the columns) and again after
an add to the list (`VectorIndex.adds`, which every add goes through) or a removal of rows
(`Columns.removals`); with it the list's memories' ids, times and positions are kept side by
side, so that the test reads a few contiguous arrays, not the columns at scattered rows (in a
question at 1M, 0.9 ms for 25k rows). New poses (`set_poses`: new columns) or a new index start
afresh.
"""

from __future__ import annotations

from typing import Any

import faiss as _faiss
import numpy as np

from ..types import Filter, Region
from ._columns import Columns
from ._vindex import VectorIndex

faiss: Any = _faiss


class ListBoxes:
    def __init__(self, vi: VectorIndex, cols: Columns) -> None:
        """`vi` is an IVF, `cols` the store's columns."""
        self.vi, self.cols = vi, cols
        self._box = np.zeros((vi.nlist, 4))  # x min, x max, y min, y max
        self._read = np.full(vi.nlist, -1, np.int64)  # vi.adds of each list when its box was read
        self._removals = cols.removals
        empty = (np.zeros(0, np.int64), np.zeros(0), np.zeros(0), np.zeros(0))
        self._rows = [empty] * vi.nlist  # per list: ids, t, x, y of its memories

    def meeting(self, region: Region) -> np.ndarray:
        """The lists whose box meets the disc's bounding square (ascending)."""
        if self.cols.removals != self._removals:
            self._read[:] = -1
            self._removals = self.cols.removals
        for lst in np.flatnonzero(self._read != self.vi.adds):
            self._read_box(int(lst))
        b, r = self._box, region.r
        meet = (b[:, 0] <= region.x + r) & (b[:, 1] >= region.x - r)
        meet &= (b[:, 2] <= region.y + r) & (b[:, 3] >= region.y - r)
        return np.flatnonzero(meet)

    def accepted(self, lists: np.ndarray, filt: Filter) -> np.ndarray:
        """The ids in `lists` (as `meeting` gave them) that the filter accepts, list by list
        (each list's in the order it holds them): the columns' tests (`select`), applied to
        those lists' memories only. Not sorted: a search's id selector takes them in any
        order."""
        if not len(lists):
            return np.zeros(0, np.int64)
        ids, t, x, y = (np.concatenate(c) for c in zip(*[self._rows[int(lst)] for lst in lists], strict=True))
        ok = np.ones(len(ids), bool)
        if filt.after is not None:
            ok &= t >= filt.after
        if filt.before is not None:
            ok &= t <= filt.before
        if filt.region is not None:  # the disc as `Columns.inside` tests it
            reg = filt.region
            dx, dy = x - reg.x, y - reg.y
            ok &= dx * dx + dy * dy <= reg.r * reg.r
        return ids[ok]

    def _ids(self, lst: int) -> np.ndarray:
        lists = self.vi.index.invlists
        size = lists.list_size(lst)
        if not size:
            return np.zeros(0, np.int64)
        return faiss.rev_swig_ptr(lists.get_ids(lst), size).view(np.int64)

    def _read_box(self, lst: int) -> None:
        ids = self._ids(lst)
        pos = self.cols.positions(ids)
        ids, pos = ids[pos >= 0], pos[pos >= 0]
        t, x, y = self.cols.col("t")[pos], self.cols.col("x")[pos], self.cols.col("y")[pos]
        self._rows[lst] = (ids.copy(), t, x, y)
        ok = np.isfinite(x) & np.isfinite(y)  # a damaged row (NaN) is in no disc
        x, y = x[ok], y[ok]
        if len(x):
            self._box[lst] = (x.min(), x.max(), y.min(), y.max())
        else:  # meets no disc
            self._box[lst] = (np.inf, -np.inf, np.inf, -np.inf)
        self._read[lst] = self.vi.adds[lst]
