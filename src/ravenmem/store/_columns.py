"""In-RAM columns (id, t, x, y, z, orientation) of every memory, for filters, the position tool
and the latest mode's view tests.

Why RAM and not SQL: a filter must be resolved on every filtered search, and a numpy pass over
1M float64 values takes about a millisecond, where SQLite needs tens of milliseconds to visit
that many rows. The columns cost 60 bytes per memory (60 MB at 1M): id, t, x, y, z as float64,
and the orientation (yaw and the quaternion, NaN without one) as float32, which is what the
latest mode needs to tell whether two memories look at the same scene (`Cameras`) without
reading records: a question compares hundreds of later memories with a place. They are a cache of
SQLite like the vector index: saved to `columns.cache` with the index (10M rows load from it in
about a second where reading them from SQLite took 14 s), and on open brought up to date from
SQLite (rows added since, deletions logged since), or reloaded from SQLite if the file is
damaged.

Why a k-d tree (scipy cKDTree) for `nearest`, not an SQLite R*Tree: the tree answers exact
k-nearest queries in O(log N), in 2-D (planar) or 3-D, with an optional radius, where an R*Tree
only answers box queries and would need a grow-the-box loop. The tree is rebuilt lazily, and
memories added since the last build (at most 1/16 of them) are scanned by brute force.
"""

from __future__ import annotations

import struct
import zlib
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..fsio import atomic_open
from ..types import Filter, Region

if TYPE_CHECKING:
    from scipy.spatial import cKDTree

_MAGIC = b"RVMCOLS2"  # 2: the orientation columns
_MAGIC_V1 = b"RVMCOLS1"  # id, t, x, y, z only: reloaded from SQLite once
_HEADER = struct.Struct("<8sqqqI4x16s")  # magic, n, max id covered, deletions reflected, crc, store uid


_FAR = 1e12  # metres: where a non-finite stored position is put for the nearest-neighbour tree


class ColumnsFileError(Exception):
    """The columns file is missing or damaged: reload the columns from SQLite."""


_BRUTE_MAX = 50_000  # below this many candidates a numpy scan beats a tree query with a mask
_BLOCK = 65_536  # rows per block of a disc test (two float64 buffers that stay in cache)


class Columns:
    def __init__(self) -> None:
        self._cap = 0
        self.n = 0
        self._ids = np.empty(0, np.int64)
        self._xyzt = np.empty((4, 0), np.float64)
        self._turn = np.empty((5, 0), np.float32)  # yaw, qx, qy, qz, qw (NaN: no quaternion)
        self.t_sorted = True
        self.removals = 0  # how many `remove` calls dropped rows (what was read of them is stale)
        self._trees: dict[bool, tuple[cKDTree, int]] = {}

    # --- columns -------------------------------------------------------------------------------
    @property
    def ids(self) -> np.ndarray:
        return self._ids[: self.n]

    def col(self, name: str) -> np.ndarray:
        return self._xyzt["xyzt".index(name), : self.n]

    def turn(self) -> np.ndarray:
        """(5, n) float32: yaw, qx, qy, qz, qw of every row (the quaternion NaN without one)."""
        return self._turn[:, : self.n]

    def append(
        self,
        ids: np.ndarray,
        t: np.ndarray,
        x: np.ndarray,
        y: np.ndarray,
        z: np.ndarray,
        turn: np.ndarray | None = None,
    ) -> None:
        """Add rows; `turn` is (5, m) yaw, qx, qy, qz, qw (None: yaw 0, no quaternion)."""
        m = len(ids)
        if m == 0:
            return
        if self.n + m > self._cap:
            cap = max(1024, 2 * self._cap, self.n + m)
            ids_new = np.empty(cap, np.int64)
            ids_new[: self.n] = self._ids[: self.n]
            cols_new = np.empty((4, cap), np.float64)
            cols_new[:, : self.n] = self._xyzt[:, : self.n]
            turn_new = np.empty((5, cap), np.float32)
            turn_new[:, : self.n] = self._turn[:, : self.n]
            self._ids, self._xyzt, self._turn, self._cap = ids_new, cols_new, turn_new, cap
        t = np.asarray(t, np.float64)
        if self.t_sorted and (np.any(np.diff(t) < 0) or (self.n and t[0] < self._xyzt[3, self.n - 1])):
            self.t_sorted = False
        sl = slice(self.n, self.n + m)
        self._ids[sl] = ids
        self._xyzt[0, sl], self._xyzt[1, sl], self._xyzt[2, sl], self._xyzt[3, sl] = x, y, z, t
        if turn is None:
            self._turn[0, sl], self._turn[1:, sl] = 0.0, np.nan
        else:
            self._turn[:, sl] = turn
        self.n += m

    def positions(self, ids: np.ndarray) -> np.ndarray:
        """The row of each id (-1 for an id not held), in the order given; by subtraction when
        the held ids are a run (no id missing between the first and the last)."""
        ids = np.asarray(ids, np.int64)
        if self.n and int(self._ids[self.n - 1]) - int(self._ids[0]) + 1 == self.n:
            pos = ids - int(self._ids[0])
            return np.where((pos >= 0) & (pos < self.n), pos, -1)
        pos = np.searchsorted(self.ids, ids)
        found = np.zeros(len(ids), bool)
        inside = pos < self.n
        found[inside] = self.ids[pos[inside]] == ids[inside]
        return np.where(found, pos, -1)

    def remove(self, ids: np.ndarray) -> int:
        """Drop the rows of `ids` (absent ones ignored); returns how many were dropped."""
        pos = self.positions(ids)
        pos = np.unique(pos[pos >= 0])
        if len(pos) == 0:
            return 0
        keep = np.ones(self.n, bool)
        keep[pos] = False
        m = int(keep.sum())
        ids, xyzt, turn = np.empty_like(self._ids), np.empty_like(self._xyzt), np.empty_like(self._turn)
        ids[:m] = self._ids[: self.n][keep]  # new arrays: a view handed out (`select`) stays as it was
        xyzt[:, :m] = self._xyzt[:, : self.n][:, keep]
        turn[:, :m] = self._turn[:, : self.n][:, keep]
        self._ids, self._xyzt, self._turn, self.n = ids, xyzt, turn, m
        self._trees.clear()
        self.removals += 1
        return len(pos)

    # --- cache file ----------------------------------------------------------------------------
    def save(self, path: Path, max_id: int, deletions: int, uid: bytes) -> None:
        """Atomically write the columns, recording the highest id and deletions they cover."""
        ids = np.ascontiguousarray(self.ids, "<i8").tobytes()
        cols = np.ascontiguousarray(self._xyzt[:, : self.n], "<f8").tobytes()
        cols += np.ascontiguousarray(self._turn[:, : self.n], "<f4").tobytes()
        crc = zlib.crc32(cols, zlib.crc32(ids))
        with atomic_open(path, "wb") as f:
            f.write(_HEADER.pack(_MAGIC, self.n, max_id, deletions, crc, uid))
            f.write(ids)
            f.write(cols)

    @classmethod
    def load(cls, path: Path, uid: bytes) -> tuple[Columns, int, int]:
        """(columns, max id covered, deletions reflected) from a file, or ColumnsFileError."""
        try:
            raw = path.read_bytes()
        except OSError as e:
            raise ColumnsFileError(f"{path.name}: {e.strerror}") from e
        if len(raw) < _HEADER.size:
            raise ColumnsFileError(f"{path.name} is truncated")
        magic, n, max_id, deletions, crc, fuid = _HEADER.unpack_from(raw)
        body = memoryview(raw)[_HEADER.size :]
        if magic == _MAGIC_V1:
            raise ColumnsFileError(f"{path.name} has the earlier layout, without the orientation")
        if magic != _MAGIC or fuid != uid or n < 0 or len(body) != 60 * n or zlib.crc32(body) != crc:
            raise ColumnsFileError(f"{path.name} is damaged or belongs to another store")
        cols = cls()
        ids = np.frombuffer(body[: 8 * n], "<i8").astype(np.int64)
        xyzt = np.frombuffer(body[8 * n : 40 * n], "<f8").reshape(4, n)
        turn = np.frombuffer(body[40 * n :], "<f4").reshape(5, n)
        cols.append(ids, xyzt[3], xyzt[0], xyzt[1], xyzt[2], turn)
        return cols, int(max_id), int(deletions)

    def extent(self) -> dict[str, float | None]:
        out: dict[str, float | None] = {}
        for c in "xyz":
            v = self.col(c)
            out[f"{c}_min"] = float(v.min()) if self.n else None
            out[f"{c}_max"] = float(v.max()) if self.n else None
        return out

    # --- filters -------------------------------------------------------------------------------
    def select(self, filt: Filter) -> np.ndarray:
        """Positions (indexes into the columns) of memories the filter accepts, ascending."""
        lo, hi = 0, self.n
        mask: np.ndarray | None = None
        t = self.col("t")
        if filt.after is not None or filt.before is not None:
            if self.t_sorted:
                lo, hi = self._span(filt)
            else:
                after = -np.inf if filt.after is None else filt.after
                before = np.inf if filt.before is None else filt.before
                mask = (t >= after) & (t <= before)
        if filt.region is not None:
            pos = self.inside(lo, hi, filt.region)
            return pos if mask is None else pos[mask[pos]]
        if mask is None:
            return np.arange(lo, hi, dtype=np.int64)
        return np.flatnonzero(mask).astype(np.int64)

    def inside(self, lo: int, hi: int, reg: Region) -> np.ndarray:
        """Positions in [lo, hi) whose (x, y) lies in the disc (dx*dx + dy*dy <= r*r, as SQL
        tests it), ascending. In blocks of `_BLOCK` rows through two reused buffers: a
        filter over half a million memories took three times as long with whole-range
        temporaries (each one pass over memory)."""
        out: list[np.ndarray] = []
        size = min(_BLOCK, max(0, hi - lo))
        bx, by = np.empty(size, np.float64), np.empty(size, np.float64)
        x, y, r2 = self.col("x"), self.col("y"), reg.r * reg.r
        for s in range(lo, hi, _BLOCK):
            e = min(hi, s + _BLOCK)
            dx = np.subtract(x[s:e], reg.x, out=bx[: e - s])
            dy = np.subtract(y[s:e], reg.y, out=by[: e - s])
            np.multiply(dx, dx, out=dx)
            np.multiply(dy, dy, out=dy)
            dx += dy
            out.append(np.flatnonzero(dx <= r2) + s)
        return np.concatenate(out).astype(np.int64) if out else np.empty(0, np.int64)

    def first_from(self, t: float, k: int, filt: Filter) -> np.ndarray:
        """Positions of the first `k` memories with time >= `t` that the filter accepts, in
        (time, id) order: `by_time` with a region, where SQLite would read every row of the
        time range to test its position. On a chronological store the positions are walked
        forward in growing steps until k are found (a disc holds a few memories of each
        pass: a few thousand positions hold the first hundreds); otherwise every accepted
        one is sorted."""
        after = t if filt.after is None else max(t, filt.after)
        filt = Filter(after=after, before=filt.before, region=filt.region)
        if k == 0:
            return np.empty(0, np.int64)
        if not self.t_sorted:
            pos = self.select(filt)
            order = np.lexsort((self.ids[pos], self.col("t")[pos]))
            return pos[order[:k]]
        tcol, reg = self.col("t"), filt.region
        lo = int(np.searchsorted(tcol, after, "left"))
        hi = self.n if filt.before is None else max(lo, int(np.searchsorted(tcol, filt.before, "right")))
        if reg is None:
            return np.arange(lo, min(hi, lo + k), dtype=np.int64)
        found: list[np.ndarray] = []
        got, step = 0, max(1024, 16 * k)
        while lo < hi and got < k:
            end = min(hi, lo + step)
            found.append(self.inside(lo, end, reg)[: k - got])
            got += len(found[-1])
            lo, step = end, step * 4
        return np.concatenate(found) if found else np.empty(0, np.int64)

    def select_ids(self, filt: Filter) -> tuple[np.ndarray, bool]:
        """(sorted ids the filter accepts, contiguous): contiguous when they are a run of
        consecutive positions, i.e. no stored id between the first and last is left out."""
        if filt.region is None and (self.t_sorted or (filt.after is None and filt.before is None)):
            lo, hi = self._span(filt)  # a run of positions: a view of the ids, not a gather
            return self.ids[lo:hi], hi > lo
        pos = self.select(filt)
        contiguous = len(pos) > 0 and int(pos[-1]) - int(pos[0]) + 1 == len(pos)
        return self.ids[pos], contiguous

    def _span(self, filt: Filter) -> tuple[int, int]:
        """[lo, hi) positions of the filter's time range (the columns are in time order)."""
        t = self.col("t")
        lo = 0 if filt.after is None else int(np.searchsorted(t, filt.after, "left"))
        hi = self.n if filt.before is None else max(lo, int(np.searchsorted(t, filt.before, "right")))
        return lo, hi

    # --- position tool ---------------------------------------------------------------------------
    def nearest(
        self, x: float, y: float, z: float | None, k: int, radius: float | None, allowed: np.ndarray | None
    ) -> list[tuple[int, float]]:
        """k nearest (position, distance), nearest first; `allowed` = positions a filter accepts."""
        if k == 0 or self.n == 0:
            return []
        planar = z is None
        q = np.array([x, y] if planar else [x, y, z], np.float64)
        if allowed is not None and len(allowed) <= _BRUTE_MAX:
            return self._brute(q, allowed, k, radius)
        tree, m = self._tree(planar)
        ok = None
        if allowed is not None:
            ok = np.zeros(self.n, bool)
            ok[allowed] = True
        cand = self._brute(q, np.arange(m, self.n), k, radius, ok)
        bound = np.inf if radius is None else radius
        kk = min(m, max(2 * k, 16))
        while kk > 0:
            d, i = tree.query(q, k=kk, distance_upper_bound=bound)
            d, i = np.atleast_1d(d), np.atleast_1d(i)
            keep = i < m
            d, i = d[keep], i[keep]
            if ok is not None:
                sel = ok[i]
                d, i = d[sel], i[sel]
            exhausted = kk >= m or keep.sum() < kk
            if len(i) >= k or exhausted:
                break
            kk = min(m, kk * 4)
        else:
            d, i = np.empty(0), np.empty(0, np.int64)
        merged = cand + [(int(p), float(dist)) for p, dist in zip(i, d, strict=True)]
        merged.sort(key=lambda p: (p[1], p[0]))
        return merged[:k]

    def _points(self, planar: bool, pos: np.ndarray | slice) -> np.ndarray:
        rows = self._xyzt[:2] if planar else self._xyzt[:3]
        return rows[:, pos].T

    def _brute(
        self, q: np.ndarray, pos: np.ndarray, k: int, radius: float | None, ok: np.ndarray | None = None
    ) -> list[tuple[int, float]]:
        if ok is not None:
            pos = pos[ok[pos]]
        if len(pos) == 0:
            return []
        d = np.sqrt(((self._points(len(q) == 2, pos) - q) ** 2).sum(axis=1))
        if radius is not None:
            keep = d <= radius
            pos, d = pos[keep], d[keep]
        if len(d) > k:
            part = np.argpartition(d, k - 1)[:k]
            pos, d = pos[part], d[part]
        out = [(int(p), float(v)) for p, v in zip(pos, d, strict=True)]
        out.sort(key=lambda p: (p[1], p[0]))
        return out

    def _tree(self, planar: bool) -> tuple[cKDTree, int]:
        built = self._trees.get(planar)
        if built is None or self.n - built[1] > max(4096, built[1] // 16):
            # a damaged row (an infinite position: set aside by the next writer) is put far
            # away rather than stopping the tree from being built
            pts = np.nan_to_num(self._points(planar, slice(0, self.n)), nan=_FAR, posinf=_FAR, neginf=-_FAR)
            from scipy.spatial import cKDTree  # here: half a second of imports a text search never needs

            built = (cKDTree(pts), self.n)
            self._trees[planar] = built
        return built
