"""The local store's vector index over its life: opened from `index.faiss` and brought up to
date from SQLite (or rebuilt when the file is missing, stale or corrupt), kept current by every
write, retrained as the store grows (flat below `ann_threshold`, an IVF above it, retrained each
time the store grows `retrain_growth`-fold), by default in a background thread while searches
keep using the old index, saved now and then and on close, and deferred during a bulk import.

`IndexLifecycle` is the part of `LocalStore` (`ravenmem.store.local`) that does this; it uses
the store's connection, lock, counters and settings, which `LocalStore.__init__` sets up. The
index itself, its file format and its search are `ravenmem.store._vindex`.
"""

from __future__ import annotations

import logging
import sqlite3
import threading
from collections.abc import Callable
from pathlib import Path

import numpy as np

from . import _sql
from ._columns import Columns
from ._vindex import IndexFileError, VectorIndex, nlist_for

log = logging.getLogger("ravenmem.store.local")  # what users see in their logs, as before the split


class _Cancelled(Exception):
    pass


class IndexLifecycle:
    """Open, maintain, rebuild (in the background), save and defer the vector index."""

    # set by LocalStore.__init__
    folder: Path
    dim: int
    read_only: bool
    ann_threshold: int
    retrain_growth: float
    codes: str
    max_nlist: int
    train_per_list: int
    background: bool
    save_min: int
    save_fraction: float
    _conn: sqlite3.Connection
    _lock: threading.RLock
    _closed: bool
    _db_path: Path
    _index_path: Path
    _cols_path: Path
    _uid: bytes
    _cols_uid: bytes
    _cols: Columns | None
    _cols_saved: tuple[int, int]
    _count: int
    _last_id: int
    _deletions: int
    _vi: VectorIndex
    _vi_upto: int
    _saved_max: int
    _dirty: bool
    _deferred: bool
    _worker: threading.Thread | None
    _cancel: threading.Event
    _retry_at: int

    def _check_open(self) -> None:  # pragma: no cover - LocalStore's
        raise NotImplementedError

    def _check_writable(self) -> None:  # pragma: no cover - LocalStore's
        raise NotImplementedError

    def _open_index(self) -> tuple[VectorIndex, int]:
        try:
            vi, covered, dels = VectorIndex.load(self._index_path, self.dim, self._uid)
            if dels > self._deletions:
                raise IndexFileError("index.faiss reflects deletions the SQLite log does not hold")
            if dels < self._deletions:  # forgotten since the file was saved
                vi.remove(_sql.deleted_since(self._conn, dels))
                self._dirty = True
            tail = int(
                self._conn.execute("SELECT COUNT(*) FROM memories WHERE id > ?", (covered,)).fetchone()[0]
            )
            if self._count - tail != vi.ntotal:
                raise IndexFileError(
                    f"index.faiss covers {vi.ntotal} vectors, SQLite has {self._count - tail} up to id {covered}"
                )
        except IndexFileError as e:
            if self._count:
                log.warning("%s: rebuilding the vector index from SQLite (%s)", self.folder, e)
            if self.read_only:
                return self._build(self._conn, self._last_id), self._last_id
            return self._build_and_save()
        if tail and vi.kind == "flat" and self._count >= self.ann_threshold and not self.read_only:
            # e.g. a bulk import was killed: build the IVF now rather than fill a flat index
            # (float32, in RAM) far past the size it is meant for
            return self._build_and_save()
        for ids, vecs in _sql.read_vectors(self._conn, covered, self._last_id):
            vi.add(ids, vecs)
        return vi, covered

    def _build_and_save(self) -> tuple[VectorIndex, int]:
        vi = self._build(self._conn, self._last_id)
        vi.save(self._index_path, self._last_id, self._uid, self._deletions)
        self._dirty = False
        return vi, self._last_id

    def _build(
        self, conn: sqlite3.Connection, upto: int, check: Callable[[], None] = lambda: None
    ) -> VectorIndex:
        """A fresh index over the SQLite vectors with id <= upto: flat when small, else IVF."""
        cur = conn.execute("SELECT id FROM memories WHERE id <= ?", (upto,))
        all_ids = np.fromiter((r[0] for r in cur), np.int64)  # 80 MB at 10M, not 10M tuples
        n = len(all_ids)
        if n < self.ann_threshold:
            vi = VectorIndex.flat(self.dim)
        else:
            n_train = min(n, self.train_per_list * nlist_for(n, self.max_nlist))
            pick = np.sort(np.random.default_rng(n).choice(all_ids, n_train, replace=False))
            del all_ids
            parts = []
            for s in range(0, n_train, 900):
                chunk = pick[s : s + 900].tolist()
                q = f"SELECT v FROM vectors WHERE id IN ({','.join('?' * len(chunk))})"
                parts.append(b"".join(r[0] for r in conn.execute(q, chunk)))
                check()
            train = np.frombuffer(b"".join(parts), np.float32).reshape(n_train, self.dim)
            vi = VectorIndex.ivf(self.dim, train, n, self.codes, self.max_nlist)
        for ids, vecs in _sql.read_vectors(conn, 0, upto):
            check()
            vi.add(ids, vecs)
        return vi

    def _needs_rebuild(self) -> bool:
        """Flat -> IVF at the threshold; the IVF is retrained each time the store doubles.

        Why so often: a robot that keeps exploring piles the frames of places it had not seen
        at training time into a few old lists. Measured on the benchmark stream: trained at
        50k, used at 100k, recall@10 (nprobe 32) 0.988 and list imbalance 2.87; retrained,
        1.000 and 1.32. At 1M, an index trained at 131k gave 0.960. The cost is about one
        extra build in total, done in the background.
        """
        n, vi = self._count, self._vi
        if vi.kind == "flat":
            return n >= self.ann_threshold
        return n < self.ann_threshold or n >= self.retrain_growth * vi.trained_n or vi.codes != self.codes

    def _maintain(self) -> None:
        """After writes: retrain when the size calls for it, else save the index now and then."""
        if self._deferred or (self._worker is not None and self._worker.is_alive()):
            return
        if self._needs_rebuild() and self._count >= self._retry_at:
            if self.background:
                self._cancel.clear()
                self._worker = threading.Thread(target=self._rebuild_bg, args=(self._last_id,), daemon=True)
                self._worker.start()
            else:
                self._swap(self._build(self._conn, self._last_id), self._last_id, self._deletions)
            return
        if self._vi_upto - self._saved_max >= max(self.save_min, self.save_fraction * self._saved_max):
            self._save()

    def _rebuild_bg(self, upto: int) -> None:
        """Build from SQLite on this thread's own connection, follow the rows added meanwhile
        (committed rows are visible to it), save, and only hold the lock for the last few.
        Repeats while the store outgrew the new index during the build."""
        conn = _sql.connect(str(self._db_path))

        def check() -> None:
            if self._cancel.is_set():
                raise _Cancelled

        try:
            while True:
                dels = self._deletions  # rows deleted after this may still be read: dropped at the swap
                vi = self._build(conn, upto, check)
                for _ in range(8):  # bounded, in case adds outpace the catch-up
                    if self._last_id - upto <= 5000:
                        break
                    latest = self._last_id  # rows up to here are committed
                    for ids, vecs in _sql.read_vectors(conn, upto, latest):
                        check()
                        vi.add(ids, vecs)
                    upto = latest
                vi.save(self._index_path, upto, self._uid, dels)
                with self._lock:
                    if self._closed:
                        return
                    self._dirty = self._catch_up(vi, upto, dels) > 0
                    self._saved_max = upto
                    if self._deferred or not self._needs_rebuild():
                        return
                    upto = self._last_id
        except _Cancelled:
            pass
        except Exception:  # pragma: no cover - logged; the old index keeps serving
            log.exception("%s: background index rebuild failed", self.folder)
            self._retry_at = int(self._count * 1.1) + 1000  # not again on every add
        finally:
            conn.close()

    def _catch_up(self, vi: VectorIndex, upto: int, dels: int) -> int:
        """Drop what was deleted since `vi` was built (after `dels` log entries), add the rows
        written since (after id `upto`), then serve from `vi`. Returns the rows dropped."""
        gone = vi.remove(_sql.deleted_since(self._conn, dels)) if self._deletions > dels else 0
        for ids, vecs in _sql.read_vectors(self._conn, upto, self._last_id):
            vi.add(ids, vecs)
        self._vi, self._vi_upto = vi, self._last_id
        return gone

    def _swap(self, vi: VectorIndex, upto: int, dels: int) -> None:
        self._catch_up(vi, upto, dels)
        self._save()

    def _save(self) -> None:
        """Write the index (and the columns, when loaded) files, covering ids <= `_vi_upto`."""
        self._vi.save(self._index_path, self._vi_upto, self._uid, self._deletions)
        self._saved_max, self._dirty = self._vi_upto, False
        if self._cols is not None and self._cols_saved != (self._last_id, self._deletions):
            self._cols.save(self._cols_path, self._last_id, self._deletions, self._cols_uid)
            self._cols_saved = (self._last_id, self._deletions)

    def rebuild_index(self) -> None:
        """Rebuild the vector index from SQLite now (e.g. after changing `ann_threshold`)."""
        self._check_writable()
        self._join_worker()
        with self._lock:
            self._check_open()
            self._swap(self._build(self._conn, self._last_id), self._last_id, self._deletions)

    def wait_for_index(self) -> None:
        """Block until a background rebuild (if any) has finished and been swapped in."""
        w = self._worker
        if w is not None:
            w.join()

    def _join_worker(self, cancel: bool = False) -> None:
        if cancel:
            self._cancel.set()
        self.wait_for_index()

    @property
    def index_kind(self) -> str:
        return self._vi.kind

    def _rebuild_due(self, n: int) -> bool:
        vi = self._vi
        if vi.kind == "flat":
            return n >= self.ann_threshold
        return n >= self.retrain_growth * vi.trained_n or vi.codes != self.codes

    def _end_bulk(self) -> None:
        """Index what a bulk import deferred: a rebuild from SQLite when one is due, else the
        deferred rows are added to the current index."""
        with self._lock:
            if self._closed:
                return
            self._deferred = False
            self._maintain()
            if (self._worker is None or not self._worker.is_alive()) and self._vi_upto < self._last_id:
                self._catch_up(self._vi, self._vi_upto, self._deletions)
        self.wait_for_index()
        with self._lock:
            if not self._closed and self._vi_upto < self._last_id:
                raise RuntimeError(
                    f"{self.folder}: the index rebuild after the import failed (see the log); "
                    "the memories are stored: call rebuild_index()"
                )
