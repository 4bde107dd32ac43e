"""The FAISS vector index of the local store, and its crash-safe file.

Two kinds: `flat` (exact inner product, IndexIDMap2 over IndexFlatIP) for small stores and
`ivf` (an inverted file, inner product) beyond a size threshold. The IVF keeps its vectors as
`sq8` codes by default (8 bits per dimension of the residual to the list centroid: 384 B per
memory at dim 384, a quarter of float32, one range widened by 20 %), so 10M memories fit in 4 GB of RAM; the store then
re-ranks the best candidates with the exact float32 vectors it keeps in SQLite. `flat` codes
(IVF-Flat, exact scores, 4x the RAM) and `fp16` are options. HNSW is not offered: on robot
streams (long runs of near-duplicate frames) its recall collapsed to 0.24-0.82 at 1M where an
IVF with nprobe 32 kept 0.997 (project measurement).

File format (`index.faiss`): a 64-byte header (magic, version, dim, max id covered, vector
count, trained size, CRC32 of the payload, the store's random uid, so that a file copied from
another memory is refused, and the number of deletions the file reflects) followed by the
`faiss.write_index` payload. It is written to a temporary file, fsynced and renamed over the
old one, so a reader sees either the old or the new index, never a torn one; the CRC catches a
corrupted file.
"""

from __future__ import annotations

import math
import struct
import zlib
from collections.abc import Iterator
from contextlib import contextmanager, nullcontext
from pathlib import Path
from typing import Any

import faiss as _faiss
import numpy as np

from ..fsio import atomic_open

faiss: Any = _faiss  # the SWIG stubs miss the keyword constructors and callback IO used here

_MAGIC = b"RVMFAISS"
_VERSION = 2
# magic, version, dim, max_id, ntotal, trained_n, crc, deletions reflected, store uid
_HEADER = struct.Struct("<8sIIqQQIq4x16s")
CODES = ("sq8", "flat", "fp16")
_SQ = {"sq8": "QT_8bit_uniform", "fp16": "QT_fp16"}
# 8-bit codes cover the residuals' trained range widened by 20 % on each side: memories added
# after training (new places) would otherwise be clipped. Measured at 400k, trained on the first
# half: with per-dimension ranges a query's own frame was among its 32 candidates 75-93 % of the
# time; with one range widened by 20 %, always (and the same recall when trained on everything).
_SQ_MARGIN = 0.2
_ROUNDING = 1e-6  # float32 scores: a list's reach is widened by this for rounding
_HNSW_ASSIGN_MIN = 20_000  # rows per add from which an HNSW graph over the centroids assigns lists


class IndexFileError(Exception):
    """The index file is missing, torn, corrupted or from another dim: rebuild from SQLite."""


def nlist_for(n: int, max_nlist: int = 4096) -> int:
    """About 4 * sqrt(N) lists, at most `max_nlist`, with at least 39 training points per list.

    Why a cap: assigning a vector to its list costs nlist dot products and k-means training
    nlist^2 x 40 of them. At 10M, 4 * sqrt(N) = 12,649 lists would assign 12k vectors/s on one
    core (a 14-minute build); 4096 lists keep lists of ~2,400 codes, which an nprobe-32 query
    scans in a few milliseconds.
    """
    return max(1, min(int(4 * math.sqrt(n)), n // 39, max_nlist))


class VectorIndex:
    def __init__(self, index: Any, dim: int, trained_n: int = 0) -> None:
        self.index = index
        self.dim = dim
        self.kind, self.codes, self._step = self._kinds()
        self.trained_n = trained_n  # how many memories the IVF was trained at (0 for flat)
        self._assigner: Any = None  # HNSW over the centroids, built for large adds
        # IVF only: the list each id lives in (-1: absent) and the list centroids, so that a
        # filtered search can probe just the lists that hold accepted ids
        self.list_of = np.full(0, -1, np.int32)
        # sq8 only: per id, whether its code may hold a clipped dimension (an extreme code), so
        # that its code score can be further from the exact one than `score_error` says; read
        # from a list's codes when `trusted` first asks about one of its ids (all lists take a
        # quarter of a second at 1M: not at open), again after an add to that list
        self._rough = np.zeros(0, bool)
        self._rough_read = np.zeros(0, bool)  # per list
        # IVF only, per list: the longest residual its codes hold (inf when a code may be
        # clipped), read with the rough flags; a floor search skips a list whose centroid
        # score plus this (plus the codes' error) is below the floor (see `reachable`)
        self._reach = np.zeros(0, np.float64)
        # IVF only, per list: how many adds reached it (what was read of a list is stale when
        # this moved on: `_boxes.ListBoxes`)
        self.adds = np.zeros(index.nlist if isinstance(index, faiss.IndexIVF) else 0, np.int64)
        self.centroids = np.zeros((0, dim), np.float32)
        if self.kind == "ivf":
            self.centroids = index.quantizer.reconstruct_n(0, index.nlist)
            lists = index.invlists
            for lst in range(index.nlist):
                size = lists.list_size(lst)
                if size:
                    ids = faiss.rev_swig_ptr(lists.get_ids(lst), size).view(np.int64)
                    self._grow(int(ids.max()))
                    self.list_of[ids] = lst

    @classmethod
    def flat(cls, dim: int) -> VectorIndex:
        return cls(faiss.IndexIDMap2(faiss.IndexFlatIP(dim)), dim)

    @classmethod
    def ivf(
        cls,
        dim: int,
        train: np.ndarray,
        n_total: int,
        codes: str = "sq8",
        max_nlist: int = 4096,
        niter: int = 10,
    ) -> VectorIndex:
        """An IVF with about 4*sqrt(n_total) lists (capped), k-means trained on `train`."""
        nlist = max(1, min(nlist_for(n_total, max_nlist), len(train) // 39))
        quantizer = faiss.IndexFlatIP(dim)
        if codes == "flat":
            index = faiss.IndexIVFFlat(quantizer, dim, nlist, faiss.METRIC_INNER_PRODUCT)
        else:
            qtype = getattr(faiss.ScalarQuantizer, _SQ[codes])
            index = faiss.IndexIVFScalarQuantizer(quantizer, dim, nlist, qtype, faiss.METRIC_INNER_PRODUCT)
            index.sq.rangestat_arg = _SQ_MARGIN
        index.cp.niter = niter
        index.cp.max_points_per_centroid = max(39, len(train) // nlist + 1)
        index.train(np.ascontiguousarray(train, np.float32))
        return cls(index, dim, trained_n=n_total)

    def _kinds(self) -> tuple[str, str, float]:
        """(kind, codes, sq8 step): `kind` is `ivf` or `flat`; `codes` how vectors are kept:
        `flat` (float32, exact scores), `sq8` or `fp16`; the step of the 8-bit grid (0 for
        other codes). Read once: asking FAISS's objects costs tens of microseconds a time."""
        kind = "ivf" if isinstance(self.index, faiss.IndexIVF) else "flat"
        if not isinstance(self.index, faiss.IndexIVFScalarQuantizer):
            return kind, "flat", 0.0
        if self.index.sq.qtype == faiss.ScalarQuantizer.QT_fp16:
            return kind, "fp16", 0.0
        return kind, "sq8", float(faiss.vector_to_array(self.index.sq.trained)[1]) / 255.0  # [min, range]

    @property
    def exact_scores(self) -> bool:
        """True when search scores are exact inner products (no re-ranking needed)."""
        return self.codes == "flat"

    def score_error(self, q: np.ndarray) -> float:
        """How far a search's score for the unit query `q` may be from the exact cosine.

        sq8 keeps each dimension of a residual to half a step of its 8-bit grid (the trained
        range over 255), so a score is off by at most half a step times the sum of |q_i|;
        twice that is returned, for residuals of memories added after training that fall a
        little outside the widened range. fp16 keeps 11 significant bits of residuals below 1
        in size. Flat codes are exact. A floor on exact scores (`LocalStore.search_vector`'s
        `min_score`) re-ranks only candidates within this of it, and every one whose code
        may be clipped (`trusted`)."""
        codes = self.codes
        if codes == "flat":
            return 0.0
        l1 = float(np.abs(q).sum())
        if codes == "fp16":
            return 2.0**-10 * l1
        return self._step * l1

    def codes_scanned(
        self, allowed: np.ndarray, q: np.ndarray | None = None, floor: float | None = None
    ) -> int:
        """How many codes an exact search restricted to `allowed` scores: every code of every
        list that holds one of them (all of them for flat); with a query and a floor, only of
        the lists that may hold a memory scoring at least the floor (`reachable`)."""
        if self.kind == "flat":
            return self.ntotal
        lists = np.flatnonzero(np.bincount(self.list_of[allowed], minlength=self.nlist))
        if q is not None and floor is not None:
            lists = lists[self.reachable(lists, self.centroids[lists] @ q, q, floor)]
        sizes = self.index.invlists
        return sum(int(sizes.list_size(int(lst))) for lst in lists)

    @property
    def ntotal(self) -> int:
        return int(self.index.ntotal)

    @property
    def nlist(self) -> int:
        return int(self.index.nlist) if isinstance(self.index, faiss.IndexIVF) else 1

    def imbalance(self) -> float:
        """FAISS's imbalance factor of the IVF lists (1.0 = even; 0.0 for flat)."""
        return float(self.index.invlists.imbalance_factor()) if self.kind == "ivf" and self.ntotal else 0.0

    def nbytes(self) -> int:
        """RAM held by the vectors: codes plus ids (and the id -> list map)."""
        if self.kind == "flat":
            return self.ntotal * (4 * self.dim + 8)
        return self.ntotal * (int(self.index.code_size) + 8) + self.list_of.nbytes

    def _grow(self, max_id: int) -> None:
        if max_id >= len(self.list_of):
            grown = np.full(max(max_id + 1, 2 * len(self.list_of)), -1, np.int32)
            grown[: len(self.list_of)] = self.list_of
            self.list_of = grown
            rough = np.zeros(len(grown), bool)
            rough[: len(self._rough)] = self._rough
            self._rough = rough

    def trusted(self, ids: np.ndarray) -> np.ndarray:
        """Per id: whether its code score is within `score_error` of the exact one (an sq8
        code holding a first or last step of the grid may be a clipped value: not trusted)."""
        ids = np.asarray(ids, np.int64)
        if self.codes != "sq8":
            return np.ones(len(ids), bool)
        self._read_lists(np.unique(self.list_of[ids]))
        return ~self._rough[ids]

    def reachable(
        self, lists: np.ndarray, centroid_scores: np.ndarray, q: np.ndarray, floor: float
    ) -> np.ndarray:
        """Which of `lists` may hold a memory scoring at least `floor` for the unit query `q`.

        A memory's score is its centroid's score plus its residual's (q . r), and q . r is at
        most |r|; its code's residual is within `score_error` of it. So a list whose centroid
        score plus its longest code residual plus that error is below the floor holds no such
        memory, and a floor search need not scan it. This is exact, unlike probing fewer
        lists: at 1M patrol memories a question's search inside a place's disc scanned 12 of
        the 47 lists holding its memories (a third of the codes) and found the same."""
        if self.kind != "ivf" or not len(lists):
            return np.ones(len(lists), bool)
        self._read_lists(lists)
        return centroid_scores + self._reach[lists] + self.score_error(q) + _ROUNDING >= floor

    def _read_lists(self, lists: np.ndarray) -> None:
        """Read the rough flags and reach of the `lists` not read since their last add."""
        if len(self._rough_read) != self.nlist:
            self._rough_read = np.zeros(self.nlist, bool)
            self._reach = np.full(self.nlist, np.inf)
        lists = lists[lists >= 0]
        for lst in lists[~self._rough_read[lists]]:
            self._read_list(int(lst))

    def _read_list(self, lst: int) -> None:
        """Flag the ids of list `lst` whose code has an extreme byte (0 or 255) somewhere, and
        set the list's reach: its longest residual as the codes keep it (inf with a flagged
        code, whose clipped residual may be longer; 0 for an empty list)."""
        lists, width = self.index.invlists, int(self.index.code_size)
        size = lists.list_size(lst)
        reach = 0.0
        if size:
            ids = faiss.rev_swig_ptr(lists.get_ids(lst), size).view(np.int64)
            codes = faiss.rev_swig_ptr(lists.get_codes(lst), size * width).reshape(size, width)
            rough = (
                ((codes == 0) | (codes == 255)).any(axis=1) if self.codes == "sq8" else np.zeros(size, bool)
            )
            self._rough[ids] = rough
            reach = math.inf if rough.any() else _longest_residual(self.index, lst, codes)
        self._reach[lst] = reach
        self._rough_read[lst] = True

    def _assign(self, x: np.ndarray) -> np.ndarray:
        """The list of each row: exact (flat quantizer) for small batches; for large ones an
        HNSW graph over the centroids, 3x faster at 4096 lists and in our measurement always
        the same list (a near miss would only cost a little recall, never correctness)."""
        if len(x) < _HNSW_ASSIGN_MIN or self.nlist < 1024:
            _, lists = self.index.quantizer.search(x, 1)
        else:
            if self._assigner is None:
                hnsw = faiss.IndexHNSWFlat(self.dim, 32, faiss.METRIC_INNER_PRODUCT)
                hnsw.hnsw.efConstruction = 40
                hnsw.add(self.centroids)
                hnsw.hnsw.efSearch = 32
                self._assigner = hnsw
            _, lists = self._assigner.search(x, 1)
        return np.ascontiguousarray(lists.ravel(), np.int64)

    def add(self, ids: np.ndarray, vecs: np.ndarray) -> None:
        x = np.ascontiguousarray(vecs, np.float32)
        xids = np.ascontiguousarray(ids, np.int64)
        if len(x) == 0:
            return
        # a live robot's small batches: one thread (see _one_thread); imports and rebuilds: all
        with _one_thread() if len(x) < _HNSW_ASSIGN_MIN else nullcontext():
            if self.kind == "flat":
                self.index.add_with_ids(x, xids)
                return
            lists = self._assign(x)
            self.index.add_core(len(x), faiss.swig_ptr(x), faiss.swig_ptr(xids), faiss.swig_ptr(lists))
        self._grow(int(xids.max()))
        self.list_of[xids] = lists
        self.adds[np.unique(lists)] += 1
        if len(self._rough_read):
            self._rough_read[lists] = False  # their new codes are read at the next `trusted`

    def remove(self, ids: np.ndarray) -> int:
        """Remove ids (absent ones are ignored); returns how many were removed."""
        xids = np.ascontiguousarray(ids, np.int64)
        if len(xids) == 0 or self.ntotal == 0:
            return 0
        if self.kind == "ivf":  # only the lists that hold them, not a scan of every list
            xids = xids[(xids >= 0) & (xids < len(self.list_of))]
            xids = xids[self.list_of[xids] >= 0]
            if len(xids) == 0:
                return 0
        removed = int(self.index.remove_ids(faiss.IDSelectorBatch(len(xids), faiss.swig_ptr(xids))))
        if self.kind == "ivf":
            self.list_of[xids] = -1
        return removed

    def search(
        self,
        q: np.ndarray,
        k: int,
        nprobe: int,
        allowed: np.ndarray | None = None,
        exact: bool = False,
        filter_budget: float = 8.0,
        contiguous: bool = False,
        floor: float | None = None,
    ) -> list[tuple[int, float]]:
        """Top-k (id, inner product), restricted exactly to the `allowed` ids when given.

        `allowed` holds unique ids (sorted when `contiguous`); `contiguous` says that no
        indexed id between its first and last is outside it (a time window on a chronological
        store), so a range test replaces the bitmap. IVF with a filter ranks only the lists that hold allowed ids by centroid
        similarity and probes the best of them until `filter_budget` times as many allowed
        vectors are compared as an unfiltered search compares (nprobe average lists), and at
        least `nprobe` of them: a wide window on a big store (10 % of 10M memories) fills the
        budget with a few crowded lists and missed neighbours in the next ones (recall 0.944
        measured before this floor). A filter
        that keeps few memories is thus searched exhaustively, and a robot's time window, which
        maps to few places and so to few lists, stays cheap. Fewer than k found -> all those
        lists. With `exact`, every list is probed (exact for flat codes).

        `floor` (a score the caller keeps hits above, exactly) leaves out the lists that
        cannot hold one (`reachable`) before any is probed: the hits at or above the floor
        are the same, found in fewer codes.
        """
        n_sel = self.ntotal if allowed is None else len(allowed)
        want = min(k, n_sel, self.ntotal)
        if want <= 0:
            return []
        if allowed is None:
            if self.kind == "flat":
                return self._run(q, want, None)
            if floor is None:
                return self._run(q, want, faiss.SearchParametersIVF(nprobe=self.nlist if exact else nprobe))
            scores = self.centroids @ q[0]
            lists = np.argsort(-scores)[: self.nlist if exact else nprobe]
            keep = lists[self.reachable(lists, scores[lists], q[0], floor)]
            return self._probe(q, want, keep, scores[keep], None, floor) if len(keep) else []
        sel, _buffer = _selector(allowed, contiguous)
        if self.kind == "flat":
            return self._run(q, want, faiss.SearchParameters(sel=sel))
        per_list = np.bincount(self.list_of[allowed], minlength=self.nlist)[: self.nlist]
        lists = np.flatnonzero(per_list)
        scores = self.centroids[lists] @ q[0]
        order = np.argsort(-scores)
        lists, scores = lists[order], scores[order]
        if floor is not None:
            keep = self.reachable(lists, scores, q[0], floor)
            lists, scores = lists[keep], scores[keep]
            if not len(lists):
                return []
        m = len(lists)
        if not exact:  # the budget, but never fewer lists than an unfiltered search probes
            budget = filter_budget * nprobe * self.ntotal / self.nlist
            m = min(m, max(nprobe, int(np.searchsorted(np.cumsum(per_list[lists]), budget)) + 1))
        hits = self._probe(q, want, lists[:m], scores[:m], sel, floor)
        if len(hits) < want and m < len(lists):
            hits = self._probe(q, want, lists, scores, sel, floor)
        return hits

    def _probe(
        self, q: np.ndarray, k: int, lists: np.ndarray, scores: np.ndarray, sel: Any, floor: float | None
    ) -> list[tuple[int, float]]:
        """The best k codes of `lists`; in a filtered search with a floor, of the lists whose
        codes are all trusted only those within `score_error` of it (a range search: no heap
        of k; a place's floor search, k = 800 over lists of background views none of which
        comes near the floor, cost half again as much with one), with the best k of the other
        lists' codes. The caller keeps the codes near the floor and the untrusted ones: all it
        kept before (the best k of every list), and an untrusted code the trusted lists' codes
        pushed out of the best k is now kept too. Unfiltered, a floor keeps many codes of the
        lists nearest the query, and collecting them all cost as much as the heap saved."""
        sure = np.isfinite(self._reach[lists]) if floor is not None and sel is not None else None
        if floor is None or sure is None or not sure.any():
            return self._preassigned(q, k, lists, scores, sel)
        radius = floor - self.score_error(q[0]) - _ROUNDING
        hits = self._in_range(q, k, radius, lists[sure], scores[sure], sel)
        if not sure.all():
            hits += self._preassigned(q, k, lists[~sure], scores[~sure], sel)
            hits.sort(key=lambda h: (-h[1], h[0]))
        return hits[:k]

    def _preassigned(
        self, q: np.ndarray, k: int, lists: np.ndarray, scores: np.ndarray, sel: Any
    ) -> list[tuple[int, float]]:
        x, iq, dq, params = _probe_args(q, lists, scores, sel)
        dist, ids = np.empty((1, k), np.float32), np.empty((1, k), np.int64)
        with _one_thread():
            self.index.search_preassigned_c(
                1,
                faiss.swig_ptr(x),
                k,
                faiss.swig_ptr(iq),
                faiss.swig_ptr(dq),
                faiss.swig_ptr(dist),
                faiss.swig_ptr(ids),
                False,
                params,
                None,
            )
        return _pairs(ids[0], dist[0])

    def _in_range(
        self, q: np.ndarray, k: int, radius: float, lists: np.ndarray, scores: np.ndarray, sel: Any
    ) -> list[tuple[int, float]]:
        """The best k codes of `lists` scoring above `radius`, best first (older first on
        ties): all of them when fewer (a floor near the typical score keeps many: they are cut
        to k before they are sorted)."""
        x, iq, dq, params = _probe_args(q, lists, scores, sel)
        res = faiss.RangeSearchResult(1)
        with _one_thread():
            self.index.range_search_preassigned_c(
                1,
                faiss.swig_ptr(x),
                float(radius),
                faiss.swig_ptr(iq),
                faiss.swig_ptr(dq),
                res,
                False,
                params,
                None,
            )
        n = int(faiss.rev_swig_ptr(res.lims, 2)[1])
        ids = faiss.rev_swig_ptr(res.labels, n).copy() if n else np.zeros(0, np.int64)
        dist = faiss.rev_swig_ptr(res.distances, n).copy() if n else np.zeros(0, np.float32)
        if n > k:
            best = np.argpartition(-dist, k - 1)[:k]
            ids, dist = ids[best], dist[best]
        order = np.lexsort((ids, -dist))
        return _pairs(ids[order], dist[order])

    def _run(self, q: np.ndarray, k: int, params: Any) -> list[tuple[int, float]]:
        with _one_thread():
            dist, ids = self.index.search(q, k, params=params)
        return _pairs(ids[0], dist[0])

    # --- file ----------------------------------------------------------------------------------
    def save(self, path: Path, max_id: int, uid: bytes, deletions: int = 0) -> None:
        """Atomically replace `path` with this index, recording that it covers ids <= max_id
        and reflects the first `deletions` entries of the store's deletion log."""
        crc = 0
        with atomic_open(path, "w+b") as f:
            f.write(b"\0" * _HEADER.size)

            def write(chunk: bytes) -> int:
                nonlocal crc
                crc = zlib.crc32(chunk, crc)
                f.write(chunk)
                return len(chunk)

            writer = faiss.PyCallbackIOWriter(write)
            faiss.write_index(self.index, writer)
            del writer
            f.seek(0)
            head = (_MAGIC, _VERSION, self.dim, max_id, self.ntotal, self.trained_n, crc, deletions, uid)
            f.write(_HEADER.pack(*head))

    @classmethod
    def load(cls, path: Path, dim: int, uid: bytes) -> tuple[VectorIndex, int, int]:
        """Read an index file; returns (index, max id covered, deletions reflected) or raises
        IndexFileError."""
        if not path.exists():
            raise IndexFileError(f"{path.name} is missing")
        with open(path, "rb") as f:
            head = f.read(_HEADER.size)
            if len(head) != _HEADER.size:
                raise IndexFileError(f"{path.name} is truncated")
            magic, version, fdim, max_id, ntotal, trained_n, crc, deletions, fuid = _HEADER.unpack(head)
            if magic != _MAGIC or version != _VERSION:
                raise IndexFileError(f"{path.name} is not a ravenmem index file of version {_VERSION}")
            if fdim != dim:
                raise IndexFileError(f"{path.name} holds dim {fdim}, expected {dim}")
            if fuid != uid:
                raise IndexFileError(f"{path.name} belongs to another store")
            seen = 0

            def read(n: int) -> bytes:
                nonlocal seen
                chunk = f.read(n)
                seen = zlib.crc32(chunk, seen)
                return chunk

            try:
                index = faiss.read_index(faiss.PyCallbackIOReader(read))
            except RuntimeError as e:
                raise IndexFileError(f"{path.name} is unreadable: {str(e).splitlines()[0]}") from e
            seen = zlib.crc32(f.read(), seen)
        if seen != crc or index.ntotal != ntotal or index.d != dim:
            raise IndexFileError(f"{path.name} failed its checksum")
        return cls(index, dim, trained_n), max_id, deletions


def _longest_residual(index: Any, lst: int, codes: np.ndarray) -> float:
    """The longest residual (vector minus centroid) that list `lst`'s codes decode to."""
    if isinstance(index, faiss.IndexIVFScalarQuantizer):
        vecs = index.sq.decode(np.ascontiguousarray(codes))
        if not index.by_residual:
            vecs = vecs - index.quantizer.reconstruct(lst)
    else:  # IVF-Flat keeps the vectors themselves
        vecs = np.ascontiguousarray(codes).view(np.float32) - index.quantizer.reconstruct(lst)
    return float(np.sqrt(np.einsum("ij,ij->i", vecs, vecs).max()))


def _probe_args(q: np.ndarray, lists: np.ndarray, scores: np.ndarray, sel: Any) -> tuple[Any, ...]:
    """What FAISS's preassigned searches take for one query probing `lists` (their centroid
    `scores`), restricted by the id selector `sel` when given: query, lists, scores, params."""
    params = faiss.SearchParametersIVF(nprobe=len(lists))
    if sel is not None:
        params.sel = sel
    return (
        np.ascontiguousarray(q, np.float32),
        np.ascontiguousarray(lists[None, :], np.int64),
        np.ascontiguousarray(scores[None, :], np.float32),
        params,
    )


def _pairs(ids: np.ndarray, dist: np.ndarray) -> list[tuple[int, float]]:
    """FAISS's result row as (id, score) pairs, empty slots (id -1) left out."""
    keep = ids >= 0
    return list(zip(ids[keep].tolist(), dist[keep].tolist(), strict=True))


def _selector(allowed: np.ndarray, contiguous: bool) -> tuple[Any, np.ndarray | None]:
    """A FAISS id selector for `allowed` ids (and the buffer it reads, to keep alive): a range
    test when contiguous (sorted), else a bitmap (any order). The bitmap's bits are packed
    only over the span of the allowed ids, not over a bool mask as long as the largest id,
    which at 10M memories cost more than the search itself."""
    if contiguous:
        return faiss.IDSelectorRange(int(allowed[0]), int(allowed[-1]) + 1), None
    lo, hi = int(allowed.min()) >> 3, int(allowed.max()) >> 3
    span = np.zeros((hi - lo + 1) * 8, bool)
    span[allowed - lo * 8] = True
    bitmap = np.zeros(hi + 1, np.uint8)
    bitmap[lo:] = np.packbits(span, bitorder="little")
    return faiss.IDSelectorBitmap(len(bitmap), faiss.swig_ptr(bitmap)), bitmap


@contextmanager
def _one_thread() -> Iterator[None]:
    """One query gains nothing from OpenMP, and on a busy machine the thread team's barrier
    costs ~50x the search itself (60 ms vs 1.2 ms at 10k x 512). The setting is per thread."""
    threads = faiss.omp_get_max_threads()
    faiss.omp_set_num_threads(1)
    try:
        yield
    finally:
        faiss.omp_set_num_threads(threads)
