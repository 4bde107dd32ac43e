"""The FAISS vector index of the local store, and its crash-safe file.

Two kinds: `flat` (exact inner product, IndexIDMap2 over IndexFlatIP) for small stores and
`ivf` (IndexIVFFlat, inner product) beyond a size threshold. IVF-Flat keeps exact vectors in
its lists, so a search that probes every list is exact; the store uses that for selective
filters. HNSW is not offered: on robot streams (long runs of near-duplicate frames) its recall
collapsed to 0.24-0.82 at 1M where IVF-Flat with nprobe 32 kept 0.997 (project measurement).

File format (`index.faiss`): a 64-byte header (magic, version, dim, max id covered, vector
count, trained size, CRC32 of the payload, the store's random uid, so that a file copied from
another memory is refused) followed by the `faiss.write_index` payload. It is
written to a temporary file, fsynced and renamed over the old one, so a reader sees either the
old or the new index, never a torn one; the CRC catches a corrupted file.
"""

from __future__ import annotations

import math
import struct
import zlib
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import faiss as _faiss
import numpy as np

from ..fsio import atomic_open

faiss: Any = _faiss  # the SWIG stubs miss the keyword constructors and callback IO used here

_MAGIC = b"RVMFAISS"
_HEADER = struct.Struct("<8sIIqQQI4x16s")  # magic, version, dim, max_id, ntotal, trained_n, crc, store uid


class IndexFileError(Exception):
    """The index file is missing, torn, corrupted or from another dim: rebuild from SQLite."""


def nlist_for(n: int) -> int:
    """About 4 * sqrt(N) lists, with at least 39 training points per list (FAISS's minimum)."""
    return max(1, min(int(4 * math.sqrt(n)), n // 39))


class VectorIndex:
    def __init__(self, index: Any, dim: int, trained_n: int = 0) -> None:
        self.index = index
        self.dim = dim
        self.trained_n = trained_n  # how many memories the IVF was trained at (0 for flat)
        # IVF only: the list each id lives in (-1: absent) and the list centroids, so that a
        # filtered search can probe just the lists that hold accepted ids
        self.list_of = np.full(0, -1, np.int32)
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
    def ivf(cls, dim: int, train: np.ndarray, n_total: int, niter: int = 10) -> VectorIndex:
        """IVF-Flat with about 4*sqrt(n_total) lists, k-means trained on `train`."""
        nlist = max(1, min(nlist_for(n_total), len(train) // 39))
        index = faiss.IndexIVFFlat(faiss.IndexFlatIP(dim), dim, nlist, faiss.METRIC_INNER_PRODUCT)
        index.cp.niter = niter
        index.cp.max_points_per_centroid = max(39, len(train) // nlist + 1)
        index.train(np.ascontiguousarray(train, np.float32))
        return cls(index, dim, trained_n=n_total)

    @property
    def kind(self) -> str:
        return "ivf" if isinstance(self.index, faiss.IndexIVF) else "flat"

    @property
    def ntotal(self) -> int:
        return int(self.index.ntotal)

    @property
    def nlist(self) -> int:
        return int(self.index.nlist) if isinstance(self.index, faiss.IndexIVF) else 1

    def imbalance(self) -> float:
        """FAISS's imbalance factor of the IVF lists (1.0 = even; 0.0 for flat)."""
        return float(self.index.invlists.imbalance_factor()) if self.kind == "ivf" and self.ntotal else 0.0

    def _grow(self, max_id: int) -> None:
        if max_id >= len(self.list_of):
            grown = np.full(max(max_id + 1, 2 * len(self.list_of)), -1, np.int32)
            grown[: len(self.list_of)] = self.list_of
            self.list_of = grown

    def add(self, ids: np.ndarray, vecs: np.ndarray) -> None:
        x = np.ascontiguousarray(vecs, np.float32)
        xids = np.ascontiguousarray(ids, np.int64)
        if self.kind == "flat":
            self.index.add_with_ids(x, xids)
            return
        _, lists = self.index.quantizer.search(x, 1)
        lists = np.ascontiguousarray(lists.ravel(), np.int64)
        self.index.add_core(len(x), faiss.swig_ptr(x), faiss.swig_ptr(xids), faiss.swig_ptr(lists))
        self._grow(int(xids.max()))
        self.list_of[xids] = lists

    def search(
        self,
        q: np.ndarray,
        k: int,
        nprobe: int,
        allowed: np.ndarray | None = None,
        exact: bool = False,
        filter_budget: float = 4.0,
    ) -> list[tuple[int, float]]:
        """Top-k (id, inner product), restricted exactly to the `allowed` ids when given.

        IVF with a filter ranks only the lists that hold allowed ids by centroid similarity and
        probes the best of them until `filter_budget` times as many allowed vectors are
        compared as an unfiltered search compares (nprobe average lists). A filter that keeps
        few memories is thus searched exactly, and a robot's time window, which maps to few
        places and so to few lists, stays cheap. Fewer than k found -> all those lists.
        """
        n_sel = self.ntotal if allowed is None else len(allowed)
        want = min(k, n_sel, self.ntotal)
        if want <= 0:
            return []
        if allowed is None:
            if self.kind == "flat":
                return self._run(q, want, None)
            return self._run(q, want, faiss.SearchParametersIVF(nprobe=self.nlist if exact else nprobe))
        mask = np.zeros(int(allowed.max()) + 1, bool)
        mask[allowed] = True
        bitmap = np.packbits(mask, bitorder="little")
        sel = faiss.IDSelectorBitmap(len(bitmap), faiss.swig_ptr(bitmap))
        if self.kind == "flat":
            return self._run(q, want, faiss.SearchParameters(sel=sel))
        per_list = np.bincount(self.list_of[allowed], minlength=self.nlist)
        lists = np.flatnonzero(per_list)
        scores = self.centroids[lists] @ q[0]
        order = np.argsort(-scores)
        lists, scores = lists[order], scores[order]
        m = len(lists)
        if not exact:
            budget = filter_budget * nprobe * self.ntotal / self.nlist
            m = min(m, int(np.searchsorted(np.cumsum(per_list[lists]), budget)) + 1)
        hits = self._preassigned(q, want, lists[:m], scores[:m], sel)
        if len(hits) < want and m < len(lists):
            hits = self._preassigned(q, want, lists, scores, sel)
        return hits

    def _preassigned(
        self, q: np.ndarray, k: int, lists: np.ndarray, scores: np.ndarray, sel: Any
    ) -> list[tuple[int, float]]:
        x = np.ascontiguousarray(q, np.float32)
        iq = np.ascontiguousarray(lists[None, :], np.int64)
        dq = np.ascontiguousarray(scores[None, :], np.float32)
        dist, ids = np.empty((1, k), np.float32), np.empty((1, k), np.int64)
        params = faiss.SearchParametersIVF(sel=sel, nprobe=len(lists))
        with _one_thread():
            self.index.search_preassigned_c(
                1, faiss.swig_ptr(x), k, faiss.swig_ptr(iq), faiss.swig_ptr(dq),
                faiss.swig_ptr(dist), faiss.swig_ptr(ids), False, params, None,
            )  # fmt: skip
        return [(int(i), float(d)) for i, d in zip(ids[0], dist[0], strict=True) if i >= 0]

    def _run(self, q: np.ndarray, k: int, params: Any) -> list[tuple[int, float]]:
        with _one_thread():
            dist, ids = self.index.search(q, k, params=params)
        return [(int(i), float(d)) for i, d in zip(ids[0], dist[0], strict=True) if i >= 0]

    # --- file ----------------------------------------------------------------------------------
    def save(self, path: Path, max_id: int, uid: bytes) -> None:
        """Atomically replace `path` with this index, recording that it covers ids <= max_id."""
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
            f.write(_HEADER.pack(_MAGIC, 1, self.dim, max_id, self.ntotal, self.trained_n, crc, uid))

    @classmethod
    def load(cls, path: Path, dim: int, uid: bytes) -> tuple[VectorIndex, int]:
        """Read an index file; returns (index, max id covered) or raises IndexFileError."""
        if not path.exists():
            raise IndexFileError(f"{path.name} is missing")
        with open(path, "rb") as f:
            head = f.read(_HEADER.size)
            if len(head) != _HEADER.size:
                raise IndexFileError(f"{path.name} is truncated")
            magic, version, fdim, max_id, ntotal, trained_n, crc, fuid = _HEADER.unpack(head)
            if magic != _MAGIC or version != 1:
                raise IndexFileError(f"{path.name} is not a ravenmem index file")
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
        return cls(index, dim, trained_n), max_id


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
