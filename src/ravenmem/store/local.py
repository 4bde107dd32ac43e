"""`local`: the embedded default store, SQLite (source of truth) + a FAISS vector index.

Files in the memory folder: `store.sqlite` (+ `-wal`/`-shm`; metadata, float32 vectors, FTS5
OCR index, deletion log, meta table), `index.faiss` (see `_vindex`) and `columns.cache` (see
`_columns`). Every `add` commits one SQLite transaction before returning, so an acknowledged
memory survives a killed process. The index and the columns are only caches: saved atomically
now and then and on close with the highest id and the number of deletions they cover; on open,
newer rows are added from SQLite and logged deletions applied, and a missing or corrupt file is
rebuilt from SQLite.

`read_only=True` (every reader: search, info, ask, a read-only service) writes nothing in the
folder: the SQLite connection is one that cannot write (`fsio.sqlite_reader`), and an index or
columns file that is stale or unusable is brought up to date in RAM only, never saved. A store
whose `store.sqlite` is missing or empty while its index or columns files are there (or, with
a reader, at all) is refused before anything is created: opening it would build an empty store
beside them and rewrite the index without its vectors (the memory checks its thumbnails too).

The index is exact (flat) below `ann_threshold` memories and an IVF above it (8-bit codes,
the best candidates re-ranked with the exact vectors from SQLite); crossing the threshold, or
growing `retrain_growth`-fold since the last training, rebuilds it from SQLite, by default in
a background thread while searches keep using the old index. `add_many` imports large batches
of precomputed embeddings: it commits them chunk by chunk and builds the index once at the end.
That index lifecycle (open, maintain, rebuild in the background, save, defer) is
`ravenmem.store._lifecycle`.
"""

from __future__ import annotations

import hashlib
import logging
import sqlite3
import threading
import uuid
from collections.abc import Iterable, Sequence
from pathlib import Path
from urllib.parse import quote

import numpy as np

from ..errors import InputError
from ..fsio import disk_full, remove_stale_temp_files, sqlite_reader
from ..types import MAX_ID, Filter, MemoryRecord, Pose
from . import _sql
from ._boxes import ListBoxes
from ._columns import Columns, ColumnsFileError
from ._common import (
    DIM_KEY,
    above,
    check_add,
    check_candidates,
    check_dim,
    check_filter,
    check_ids,
    check_limit,
    check_min_score,
    check_point,
    check_poses,
    check_query,
    import_key,
    query_words,
    rank_text,
    skip_rows,
)
from ._lifecycle import IndexLifecycle
from ._tail import Tail, capacity
from ._vindex import CODES
from .base import STORES, Cameras, SourceFrames
from .presence import check_present

log = logging.getLogger(__name__)
UID_KEY = "store.uid"
POSES_KEY = "store.poses"  # bumped by every `set_poses`: the columns cache is of one pose epoch
_MAX_T = 1.7976931348623157e308  # every finite time is within +-this; inf and text are not
_RERANK_MIN = 32  # candidates re-ranked per query at least (k = 1 still gets a margin)
# SQLite reads the database through a memory map this large at most (capped at its build's
# limit, 2 GB in CPython's): a vector or record read is then a copy from the page cache, not a
# read() call; 200 random vectors at 1M memories: 0.76 -> 0.24 ms (docs/store.md, "Reads")
_MMAP_BYTES = 1 << 31
_CODE_EXACT_MAX = 50_000  # an exact search with a floor scores up to this many codes, not vectors
_CODES_PER_READ = 256  # codes scored in the time of one vector read from SQLite (measured at 1M)


class LocalStore(IndexLifecycle):
    """FAISS + SQLite store in one folder; thread-safe (one lock around index and connection)."""

    def __init__(
        self,
        folder: Path,
        dim: int,
        ann_threshold: int = 50_000,
        nprobe: int = 32,
        retrain_growth: float = 2.0,
        filter_budget: float = 8.0,
        background: bool = True,
        save_min: int = 10_000,
        save_fraction: float = 0.25,
        train_per_list: int = 40,
        synchronous: str = "FULL",
        codes: str = "sq8",
        rerank: int = 4,
        max_nlist: int = 4096,
        read_only: bool = False,
    ) -> None:
        if folder.exists() and not folder.is_dir():
            raise InputError(f"{folder}: not a folder (the local store needs a memory folder)")
        if not isinstance(dim, int) or dim <= 0:
            raise InputError(f"dim: expected a positive integer, got {dim!r}")
        if synchronous.upper() not in ("FULL", "NORMAL", "EXTRA"):
            raise InputError(f"synchronous: expected FULL, NORMAL or EXTRA, got {synchronous!r}")
        if codes not in CODES:
            raise InputError(f"codes: expected one of {', '.join(CODES)}, got {codes!r}")
        if rerank < 1 or max_nlist < 1:
            raise InputError(f"rerank and max_nlist must be >= 1, got {rerank} and {max_nlist}")
        check_present(folder, read_only)
        if not read_only:
            folder.mkdir(parents=True, exist_ok=True)
        check_own_database(folder / "store.sqlite")
        self.folder, self.dim, self.read_only = folder, dim, read_only
        self.ann_threshold, self.nprobe, self.retrain_growth = ann_threshold, nprobe, retrain_growth
        self.filter_budget, self.codes, self.rerank, self.max_nlist = filter_budget, codes, rerank, max_nlist
        self.background, self.save_min, self.save_fraction = background, save_min, save_fraction
        self.train_per_list = train_per_list
        self._db_path, self._index_path = folder / "store.sqlite", folder / "index.faiss"
        self._cols_path = folder / "columns.cache"
        self._lock = threading.RLock()
        self._closed = False
        if read_only:
            self._conn = sqlite_reader(self._db_path)
        else:
            self._conn = _sql.connect(str(self._db_path), synchronous.upper())
        try:
            self._conn.execute(f"PRAGMA mmap_size={_MMAP_BYTES}")
            if read_only:
                self._tokenizer = _sql.read_schema(self._conn, str(self._db_path))
            else:
                self._conn.execute("PRAGMA journal_size_limit=8388608")
                self._tokenizer = _sql.create_schema(self._conn)
            check_dim(str(folder), self.get_meta(DIM_KEY), dim)
            if self.get_meta(DIM_KEY) is None and not read_only:
                self.set_meta(DIM_KEY, str(dim))
            if self.get_meta(UID_KEY) is None and not read_only:
                self.set_meta(UID_KEY, uuid.uuid4().hex)
            self._uid = bytes.fromhex(self.get_meta(UID_KEY) or "")
            self._cols_uid = _columns_uid(self._uid, self.get_meta(POSES_KEY))
        except BaseException:
            self._conn.close()
            self._closed = True
            raise
        self._deletions, top_deleted = _sql.deletions(self._conn)
        top = int(self._conn.execute("SELECT COALESCE(MAX(id), 0) FROM memories").fetchone()[0])
        self._last_id = max(top, top_deleted)  # ids never repeat, not even a deleted newest one
        self._count = int(self._conn.execute("SELECT COUNT(*) FROM memories").fetchone()[0])
        self._cols: Columns | None = None
        self._tail: Tail | None = None  # the newest vectors in RAM, loaded at first use
        self._boxes: ListBoxes | None = None  # where each IVF list's memories are, read at first use
        self._cols_saved = (-1, -1)  # (max id, deletions) the columns file covers
        self._worker: threading.Thread | None = None
        self._cancel = threading.Event()
        self._retry_at = 0
        self._deferred = False  # a bulk import is skipping the index (it is rebuilt at the end)
        self._dirty = False  # deletions the index file does not reflect
        if not read_only:
            for target in ("index.faiss.", "columns.cache."):  # never one a live process writes
                remove_stale_temp_files(folder, target=target)
        self._vi, self._saved_max = self._open_index()
        self._vi_upto = self._last_id  # every row up to this id is in the index, none after
        if read_only:
            self._saved_max = self._vi_upto  # nothing to save, ever
        else:
            self._set_aside_damaged()
            self._maintain()

    def _set_aside_damaged(self) -> None:
        """A writer's open moves rows with values out of range (`_sql.damaged`) into the
        `memories_aside` table, so that no later read or write trips over them."""
        bad = _sql.damaged(self._conn)
        if len(bad) == 0:
            return
        gone = _sql.set_aside(self._conn, bad)
        self._deletions += len(gone)
        self._count -= len(gone)
        self._vi.remove(gone)
        self._dirty = True
        shown = ", ".join(str(i) for i in gone[:10].tolist()) + (" ..." if len(gone) > 10 else "")
        log.warning(
            "%s: %d memories with a damaged time or pose (id %s) set aside in its table %s",
            self._db_path,
            len(gone),
            shown,
            _sql.ASIDE,
        )

    # --- writes ----------------------------------------------------------------------------------
    def add(self, records: Sequence[MemoryRecord], embeddings: np.ndarray) -> list[int]:
        """Store a batch durably (one transaction) and index it; returns the new ids."""
        self._check_writable()
        emb = check_add(records, embeddings, self.dim)
        if not len(records):
            return []
        with self._lock:
            self._check_open()
            ids = self._insert(records, emb)
            self._maintain()
        return ids.tolist()

    def _insert(
        self, records: Sequence[MemoryRecord], emb: np.ndarray, meta: dict[str, str] | None = None
    ) -> np.ndarray:
        """Commit one batch, then index it (unless a bulk import defers indexing)."""
        ids = np.arange(self._last_id + 1, self._last_id + 1 + len(records), dtype=np.int64)
        _sql.insert(self._conn, ids.tolist(), records, emb, meta)
        self._last_id, self._count = int(ids[-1]), self._count + len(records)
        if not self._deferred:
            self._vi.add(ids, emb)
            self._vi_upto = self._last_id
        if self._tail is not None:
            self._tail.append(ids, emb)
        if self._cols is not None:
            cols = np.array([(r.t, r.pose.x, r.pose.y, r.pose.z) for r in records], np.float64).T
            self._cols.append(ids, cols[0], cols[1], cols[2], cols[3], Cameras.of(records).poses[:, 2:].T)
        return ids

    def add_many(
        self, batches: Iterable[tuple[Sequence[MemoryRecord], np.ndarray]], resume: str | None = None
    ) -> int:
        """Import many memories with precomputed embeddings; returns how many were added.

        Each batch is committed in one transaction (durable when the next one starts), so a
        killed import leaves whole batches. With `resume`, a name for this import, the count
        of input rows committed is kept in the same transactions, and calling again with the
        same name skips them: rerun the same import after a crash and it continues. Indexing is
        deferred while the store grows past the point where the index would be rebuilt anyway
        (crossing `ann_threshold`, or doubling), and done once, from SQLite, at the end; the
        imported memories are searchable when this returns.
        """
        self._check_writable()
        key = import_key(resume)
        done = int(self.get_meta(key) or 0) if key else 0
        added = 0
        self.wait_for_index()  # a rebuild already under way finishes first
        try:
            for records, embeddings in skip_rows(batches, done):
                emb = check_add(records, embeddings, self.dim)
                if not len(records):
                    continue
                done += len(records)
                with self._lock:
                    self._check_open()
                    if not self._deferred and self._vi_upto == self._last_id:
                        self._deferred = self._rebuild_due(self._count + len(records))
                    self._insert(records, emb, {key: str(done)} if key else None)
                added += len(records)
        finally:
            self._end_bulk()
        return added

    def set_ocr_text(self, ids: Sequence[int], texts: Sequence[str]) -> int:
        """Replace the OCR text of stored memories (`TextStore`)."""
        if len(ids) != len(texts):
            raise InputError(f"{len(ids)} ids but {len(texts)} texts")
        with self._lock:
            self._check_open()
            return _sql.set_ocr_text(self._conn, ids, texts)

    def delete(self, ids: Iterable[int]) -> int:
        """Forget memories: their rows, vectors and OCR entries go in one SQLite transaction
        (a crash leaves all of them or none), then the index and columns drop them. Unknown
        ids are ignored; returns how many memories were deleted."""
        self._check_writable()
        want = check_ids(ids)
        if len(want) == 0:
            return 0
        with self._lock:
            self._check_open()
            gone = _sql.delete(self._conn, want)
            if len(gone) == 0:
                return 0
            self._deletions += len(gone)
            self._count -= len(gone)
            self._vi.remove(gone)
            if self._cols is not None:
                self._cols.remove(gone)
            self._dirty = True
        return len(gone)

    def set_poses(self, ids: Sequence[int], poses: Sequence[Pose]) -> int:
        """New poses in one SQLite transaction (all or none; KeyError for an id not stored).
        The vectors and the index stay; the columns are reloaded from SQLite, and the pose
        epoch the transaction bumps makes every `columns.cache` written before it (by this
        process or a reader's) stale, so no old position is ever read back."""
        want, new = check_poses(ids, poses)
        if not want:
            return 0
        with self._lock:
            self._check_open()
            epoch = uuid.uuid4().hex
            n = _sql.set_poses(self._conn, want, new, {POSES_KEY: epoch})
            self._cols_uid = _columns_uid(self._uid, epoch)
            self._cols, self._cols_saved = None, (-1, -1)
        return n

    def select(self, filt: Filter | None = None) -> np.ndarray:
        """Ids (sorted, int64) of the memories a filter accepts; every id without one. Read-only,
        and a time range is a view of the columns, not a copy (half a million ids copied cost
        0.4 ms of a question): later adds and removals leave it as it was (`Columns.remove`
        makes new arrays)."""
        filt = check_filter(filt)
        with self._lock:
            self._check_open()
            cols = self._columns()
            out = (cols.ids if filt is None else cols.select_ids(filt)[0]).view()
            out.flags.writeable = False
            return out

    # --- tools -----------------------------------------------------------------------------------
    def search_vector(
        self,
        query: np.ndarray,
        k: int,
        filt: Filter | None = None,
        exact: bool = False,
        min_score: float | None = None,
        candidates: int | None = None,
    ) -> list[tuple[int, float]]:
        """Top-k (id, cosine). The IVF's 8-bit codes only pick candidates: the best
        `rerank` x k (or `candidates`, at least k) are scored again with their exact vectors
        from SQLite. `exact=True` is the ground truth (a scan of every vector the filter
        accepts; slow on big stores).

        `min_score` keeps only hits scoring at least that: only the candidates whose code
        score is within the codes' error (`VectorIndex.score_error`) of it are read and
        re-ranked, so "which of these score above t" reads the few that do, not `rerank` x k
        vectors. With `exact` and a filter that keeps at most `_CODE_EXACT_MAX` memories, every
        one of them is scored from its code and only those near or above the floor are read:
        the same answer as the scan, from a fraction of the reads."""
        q, k, filt = check_query(query, self.dim), check_limit(k), check_filter(filt)
        floor, candidates = check_min_score(min_score), check_candidates(candidates, k)
        with self._lock:
            self._check_open()
            if k == 0 or self._count == 0:
                return []
            allowed, contiguous = None, False
            if filt is not None:
                allowed, contiguous = self._accepted(filt, q[0], floor, exact)
                if len(allowed) == 0:
                    return []
            vi = self._vi
            if exact and not vi.exact_scores and allowed is not None:
                tail = self._tail_covering(allowed)
                if tail is not None:  # the newest memories: exact scores from RAM
                    ids, scores = tail.scores(allowed, q[0])
                    if floor is not None:  # those below it first: a thousand sorted for a few
                        keep = scores.astype(np.float64) >= floor
                        ids, scores = ids[keep], scores[keep]
                    return _top(ids, scores, k)
            if exact and not vi.exact_scores:
                if floor is None or not self._codes_cover(allowed, q[0], floor):
                    return above(self._scan(q, k, allowed, contiguous), floor)
                assert allowed is not None  # _codes_cover refuses the whole store
                want = len(allowed)  # every accepted memory's code score
            else:
                want = k if vi.exact_scores else candidates or max(self.rerank * k, _RERANK_MIN)
            hits = vi.search(q, want, self.nprobe, allowed, exact, self.filter_budget, contiguous, floor)
            if vi.exact_scores:
                return above(hits[:k], floor)
            if floor is not None and hits:
                near = floor - vi.score_error(q[0])
                sure = vi.trusted(np.array([i for i, _ in hits], np.int64))
                hits = [h for h, ok in zip(hits, sure, strict=True) if h[1] >= near or not ok]
            return above(self._rescore(q, [i for i, _ in hits], k), floor)

    def _accepted(
        self, filt: Filter, q: np.ndarray, floor: float | None, exact: bool
    ) -> tuple[np.ndarray, bool]:
        """(ids a search may score, contiguous): the filter's (`Columns.select_ids`, sorted),
        except that an IVF search in a disc with a floor gets only those in the lists that
        can hold a hit: lists whose memories' box meets the disc (`ListBoxes`) and that can
        reach the floor (`VectorIndex.reachable`), list by list, unsorted (the search's id
        selector takes any order). The lists it then probes, and so its hits, are the same;
        the positions tested are those lists' few, not all of the time range's."""
        vi = self._vi
        if (
            filt.region is None
            or floor is None
            or exact
            or vi.kind != "ivf"
            or self._vi_upto != self._last_id
        ):
            return self._columns().select_ids(filt)
        cols = self._columns()
        if self._boxes is None or self._boxes.vi is not vi or self._boxes.cols is not cols:
            self._boxes = ListBoxes(vi, cols)
        lists = self._boxes.meeting(filt.region)
        lists = lists[vi.reachable(lists, vi.centroids[lists] @ q, q, floor)]
        return self._boxes.accepted(lists, filt), False

    def _tail_covering(self, allowed: np.ndarray) -> Tail | None:
        """The tail (`_tail`) when it holds every stored one of `allowed`, loaded when first
        needed (the newest `cap` memories' vectors, one read)."""
        if self._tail is None:
            ids = self._columns().ids
            cap = capacity(self.dim)
            after = int(ids[-cap]) - 1 if len(ids) > cap else -1
            if len(allowed) == 0 or int(allowed[0]) <= after:
                return None  # reaches further back than a tail would: not loaded for it
            got = list(_sql.read_vectors(self._conn, after, self._last_id))
            vids = np.concatenate([i for i, _ in got]) if got else np.empty(0, np.int64)
            vecs = np.concatenate([v for _, v in got]) if got else np.empty((0, self.dim), np.float32)
            self._tail = Tail(self.dim, after, vids, vecs)
        return self._tail if self._tail.covers(allowed) else None

    def _codes_cover(self, allowed: np.ndarray | None, q: np.ndarray, floor: float) -> bool:
        """Whether an exact search with a floor should score `allowed` from the index's codes:
        every stored memory is in the index (none deferred), and the lists that hold them and
        may reach the floor are short enough that scoring all their codes costs less than
        reading the accepted vectors (a code costs about a 256th of a read; a time window of
        a robot that saw the same few scenes all along spreads over a few crowded lists)."""
        if allowed is None or len(allowed) > _CODE_EXACT_MAX or self._vi_upto != self._last_id:
            return False
        return self._vi.codes_scanned(allowed, q, floor) <= _CODES_PER_READ * len(allowed)

    def _rescore(self, q: np.ndarray, ids: Sequence[int], k: int) -> list[tuple[int, float]]:
        """Exact cosine of `ids` from their SQLite vectors, best k (older first on ties)."""
        if not ids:
            return []
        vecs = _sql.fetch_vectors(self._conn, ids)
        got = np.fromiter(vecs.keys(), np.int64, len(vecs))
        mat = np.frombuffer(b"".join(vecs.values()), np.float32).reshape(len(got), self.dim)
        return _top(got, mat @ q[0], k)

    def _scan(
        self, q: np.ndarray, k: int, allowed: np.ndarray | None, contiguous: bool
    ) -> list[tuple[int, float]]:
        """Exact top-k by reading every accepted vector from SQLite (the ground truth)."""
        if allowed is None or contiguous:
            lo, hi = (0, self._last_id) if allowed is None else (int(allowed[0]) - 1, int(allowed[-1]))
            chunks = _sql.read_vectors(self._conn, lo, hi)
        else:
            chunks = (
                (
                    np.array(list(v), np.int64),
                    np.frombuffer(b"".join(v.values()), np.float32).reshape(len(v), -1),
                )
                for v in (
                    _sql.fetch_vectors(self._conn, allowed[s : s + 50_000])
                    for s in range(0, len(allowed), 50_000)
                )
            )
        best_ids, best = np.empty(0, np.int64), np.empty(0, np.float32)
        for ids, vecs in chunks:
            if len(ids) == 0:
                continue
            ids = np.concatenate([best_ids, ids])
            scores = np.concatenate([best, vecs @ q[0]])
            keep = np.argpartition(-scores, k - 1)[:k] if len(scores) > k else np.arange(len(scores))
            best_ids, best = ids[keep], scores[keep]
        return _top(best_ids, best, k)

    def search_text(self, text: str, k: int, filt: Filter | None = None) -> list[tuple[int, float]]:
        """Top-k (id, score in [0, 1]) over OCR text: FTS5 finds candidates, `ocr_score` ranks."""
        k, filt = check_limit(k), check_filter(filt)
        words = query_words(text or "")
        if not words or k == 0:
            return []
        cond, args = _sql.where(filt, "m.")
        trigram = self._tokenizer == "trigram"
        terms = [w for w in words if len(w) >= 3] if trigram else words
        if terms:
            match = " OR ".join(f'"{w}"' + ("" if trigram else "*") for w in terms)
            sql = (
                "SELECT m.id, m.ocr_text FROM ocr JOIN memories m ON m.id = ocr.rowid WHERE ocr MATCH ?"
                + (f" AND {cond}" if cond else "")
                + " ORDER BY ocr.rank LIMIT ?"
            )
            params: list[object] = [match, *args, max(500, 50 * k)]
        else:  # only words shorter than a trigram: scan the memories that have text
            sql = "SELECT m.id, m.ocr_text FROM memories m WHERE m.ocr_text != ''" + (
                f" AND {cond}" if cond else ""
            )
            params = list(args)
        with self._lock:
            self._check_open()
            rows = self._conn.execute(sql, params).fetchall()
        return rank_text(text, rows, k)

    def by_time(self, t: float, k: int, filt: Filter | None = None) -> list[MemoryRecord]:
        """The k memories with timestamp >= t, oldest first (ties by id)."""
        k, filt = check_limit(k), check_filter(filt)
        if not _finite(t) and t not in (float("inf"), float("-inf")):
            raise InputError(f"t: expected a timestamp in seconds, got {t!r}")
        if filt is not None and filt.region is not None:  # positions from the columns, as select's
            with self._lock:
                self._check_open()
                cols = self._columns()
                want = cols.ids[cols.first_from(float(t), k, filt)].tolist()
                found = self._records(want)
            return [found[i] for i in want if i in found]
        cond, args = _sql.where(filt)
        sql = (
            f"SELECT {_sql.COLS} FROM memories WHERE t >= ?"
            + (f" AND {cond}" if cond else "")
            + " ORDER BY t, id LIMIT ?"
        )
        with self._lock:
            self._check_open()
            rows = self._conn.execute(sql, [float(t), *args, k]).fetchall()
        return [_sql.to_record(r) for r in rows]

    def cameras(self, t: float, k: int, filt: Filter | None = None) -> Cameras:
        """`by_time`'s memories as cameras, from the in-RAM columns (no record is read)."""
        k, filt = check_limit(k), check_filter(filt)
        if not _finite(t) and t not in (float("inf"), float("-inf")):
            raise InputError(f"t: expected a timestamp in seconds, got {t!r}")
        with self._lock:
            self._check_open()
            cols = self._columns()
            return _cameras(cols, cols.first_from(float(t), k, filt or Filter()))

    def cameras_of(self, ids: Sequence[int]) -> Cameras:
        """The cameras of the stored ones of `ids`, in the order given, from the in-RAM columns."""
        want = np.asarray([int(i) for i in ids], np.int64)
        with self._lock:
            self._check_open()
            cols = self._columns()
            pos = cols.positions(want)
            return _cameras(cols, pos[pos >= 0])

    def time_order(self, ids: Sequence[int]) -> np.ndarray | None:
        """Each id's place in (time, id) order (-1: not stored): its position in the in-RAM
        columns when their ids follow time (None otherwise)."""
        want = np.asarray([int(i) for i in ids], np.int64)
        with self._lock:
            self._check_open()
            cols = self._columns()
            return cols.positions(want) if cols.t_sorted else None

    def nearest(
        self,
        x: float,
        y: float,
        z: float | None,
        k: int,
        radius: float | None = None,
        filt: Filter | None = None,
    ) -> list[tuple[int, float]]:
        """The k spatially nearest (id, metres), nearest first; planar when z is None."""
        k, filt = check_limit(k), check_filter(filt)
        check_point(x, y, z, radius)
        with self._lock:
            self._check_open()
            cols = self._columns()
            allowed = None if filt is None else cols.select(filt)
            hits = cols.nearest(float(x), float(y), None if z is None else float(z), k, radius, allowed)
            ids = cols.ids
            return [(int(ids[p]), d) for p, d in hits]

    # --- records and meta --------------------------------------------------------------------------
    def get(self, ids: Sequence[int], with_embeddings: bool = False) -> list[MemoryRecord]:
        """Records in the order of `ids`; an unknown id raises KeyError."""
        want = [int(i) for i in ids]
        with self._lock:
            self._check_open()
            found = self._records(want, with_embeddings)
        missing = [i for i in want if i not in found]
        if missing:
            raise KeyError(f"unknown memory id(s): {missing[:10]}")
        return [found[i] for i in want]

    def _records(self, ids: Sequence[int], with_embeddings: bool = False) -> dict[int, MemoryRecord]:
        """id -> record of the `ids` stored (read in chunks of 900; caller holds the lock)."""
        found: dict[int, MemoryRecord] = {}
        uniq = sorted({i for i in ids if 0 <= i <= MAX_ID})  # others cannot be stored: unknown
        for s in range(0, len(uniq), 900):
            chunk = uniq[s : s + 900]
            marks = ",".join("?" * len(chunk))
            rows = self._conn.execute(f"SELECT {_sql.COLS} FROM memories WHERE id IN ({marks})", chunk)
            vecs = {}
            if with_embeddings:
                vecs = dict(
                    self._conn.execute(f"SELECT id, v FROM vectors WHERE id IN ({marks})", chunk).fetchall()
                )
            for row in rows.fetchall():
                found[int(row[0])] = _sql.to_record(row, vecs.get(row[0]) if with_embeddings else None)
        return found

    def source_frames(self, source: str) -> SourceFrames:
        """Every memory from `source`, sorted by (frame_index, id), via the source index."""
        if not isinstance(source, str):
            raise InputError(f"source: expected a string, got {type(source).__name__}")
        with self._lock:
            self._check_open()
            rows = _sql.source_frames(self._conn, source)
        return SourceFrames.from_rows(rows)

    def count(self, filt: Filter | None = None) -> int:
        filt = check_filter(filt)
        if filt is None:
            return self._count
        with self._lock:
            self._check_open()
            return len(self._columns().select_ids(filt)[0])

    def stats(self) -> dict[str, object]:
        """Counts, time span, spatial extent, index kind, bytes on disk (SQLite + caches)."""
        with self._lock:
            self._check_open()
            t_min, t_max = self._conn.execute(  # of finite times: a damaged row's is not one
                "SELECT MIN(t), MAX(t) FROM memories WHERE t BETWEEN ? AND ?", (-_MAX_T, _MAX_T)
            ).fetchone()
            ext = self._columns().extent()
            files = [
                self._db_path,
                self._db_path.with_name("store.sqlite-wal"),
                self._index_path,
                self._cols_path,
            ]
            size = sum(p.stat().st_size for p in files if p.exists())
            vi = self._vi
            return {
                "backend": "local",
                "count": self._count,
                "dim": self.dim,
                "t_min": t_min,
                "t_max": t_max,
                **ext,
                "index": vi.kind,
                "codes": vi.codes if vi.kind == "ivf" else "flat",
                "nlist": vi.nlist,
                "ivf_imbalance": round(vi.imbalance(), 3),
                "nprobe": self.nprobe,
                "rerank": 0 if vi.exact_scores else self.rerank,
                "index_ram_bytes": vi.nbytes(),
                "deleted": self._deletions,
                "bytes": size,
                "bytes_per_memory": size / self._count if self._count else None,
                "ocr_tokenizer": self._tokenizer,
            }

    def get_meta(self, key: str) -> str | None:
        with self._lock:
            self._check_open()
            row = self._conn.execute("SELECT value FROM meta WHERE key = ?", (key,)).fetchone()
        return None if row is None else str(row[0])

    def set_meta(self, key: str, value: str) -> None:
        if not isinstance(key, str) or not isinstance(value, str):
            raise InputError(
                f"meta: key and value must be strings, got {type(key).__name__}, {type(value).__name__}"
            )
        self._check_writable()
        with self._lock:
            self._check_open()
            self._conn.execute("INSERT OR REPLACE INTO meta (key, value) VALUES (?, ?)", (key, value))

    def close(self) -> None:
        """Finish (or cancel) a background rebuild, save the caches, checkpoint the WAL."""
        if getattr(self, "_closed", True):
            return
        self._join_worker(cancel=True)
        with self._lock:
            if self._closed:
                return
            if self.read_only:  # nothing of this store was written: nothing to save
                self._conn.close()
                self._closed = True
                return
            try:
                if self._saved_max != self._vi_upto or self._dirty:
                    self._save()
                elif self._cols is not None and self._cols_saved != (self._last_id, self._deletions):
                    self._cols.save(self._cols_path, self._last_id, self._deletions, self._cols_uid)
                self._conn.execute("PRAGMA wal_checkpoint(TRUNCATE)")
            except Exception as e:  # the caches are rebuilt from SQLite on the next open
                if disk_full(e) is None:
                    raise
                log.warning(
                    "%s: index and columns not saved (%s); rebuilt at the next open",
                    self.folder,
                    disk_full(e),
                )
            finally:
                self._conn.close()
                self._closed = True

    def __enter__(self) -> LocalStore:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- helpers ---------------------------------------------------------------------------------
    def _check_open(self) -> None:
        if self._closed:
            raise InputError(f"{self.folder}: the store is closed")

    def _check_writable(self) -> None:
        if getattr(self, "read_only", False):
            raise InputError(f"{self.folder}: the store was opened read-only (open it writable to change it)")

    def _columns(self) -> Columns:
        """The in-RAM columns, loaded on first use from `columns.cache` brought up to date
        (deletions logged since, rows added since), or from SQLite when the file is unusable."""
        if self._cols is None:
            cols = None
            try:
                cols, covered, dels = Columns.load(self._cols_path, self._cols_uid)
                if dels > self._deletions:
                    raise ColumnsFileError("columns.cache reflects deletions the SQLite log does not hold")
                if dels < self._deletions:
                    cols.remove(_sql.deleted_since(self._conn, dels))
                self._load_columns(cols, covered)
                if cols.n != self._count:
                    raise ColumnsFileError(f"columns.cache holds {cols.n} rows, SQLite {self._count}")
                self._cols_saved = (covered, dels)
            except ColumnsFileError as e:
                if self._cols_path.exists():
                    log.warning("%s: reloading the columns from SQLite (%s)", self.folder, e)
                cols = Columns()
                self._load_columns(cols, 0)
            self._cols = cols
        return self._cols

    def _load_columns(self, cols: Columns, after: int) -> None:
        last = after
        while True:
            rows = self._conn.execute(
                "SELECT id, t, x, y, z, yaw, qx, qy, qz, qw FROM memories WHERE id > ? ORDER BY id LIMIT 200000",
                (last,),
            ).fetchall()
            if not rows:
                break
            try:
                a = np.array(rows, np.float64)
            except (TypeError, ValueError):  # a damaged row (text in a REAL column): NaN here
                a = np.array([[_number(v) for v in r] for r in rows], np.float64)
            cols.append(a[:, 0].astype(np.int64), a[:, 1], a[:, 2], a[:, 3], a[:, 4], a[:, 5:].T)
            last = int(a[-1, 0])


def _cameras(cols: Columns, pos: np.ndarray) -> Cameras:
    """The cameras of the columns' rows `pos`."""
    poses = np.empty((len(pos), 7), np.float64)
    poses[:, 0], poses[:, 1] = cols.col("x")[pos], cols.col("y")[pos]
    poses[:, 2:] = cols.turn()[:, pos].T
    return Cameras(cols.ids[pos], cols.col("t")[pos], poses)


def _columns_uid(uid: bytes, epoch: str | None) -> bytes:
    """The id a columns cache must carry: the store's, mixed with its pose epoch when poses
    were ever changed (16 bytes, as the file header holds)."""
    if not epoch:
        return uid
    return hashlib.blake2b(uid + epoch.encode(), digest_size=16).digest()


def _top(ids: np.ndarray, scores: np.ndarray, k: int) -> list[tuple[int, float]]:
    """The k best (id, score), best first, the older memory first on ties."""
    order = np.lexsort((ids, -scores))[:k]
    return list(zip(ids[order].tolist(), scores[order].astype(np.float64).tolist(), strict=True))


def _number(v: object) -> float:
    """A stored column value as a float, NaN when it is not a number (a damaged row, which the
    next writer sets aside)."""
    try:
        return float(v)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return float("nan")


def _finite(v: object) -> bool:
    try:
        return bool(np.isfinite(float(v)))  # type: ignore[arg-type]
    except (TypeError, ValueError):
        return False


_OPTIONS = {
    "read_only": bool,
    "ann_threshold": int,
    "nprobe": int,
    "retrain_growth": float,
    "filter_budget": float,
    "background": bool,
    "save_min": int,
    "save_fraction": float,
    "train_per_list": int,
    "synchronous": str,
    "codes": str,
    "rerank": int,
    "max_nlist": int,
}


def check_own_database(db: Path) -> None:
    """Refuse, before anything writes to it, a `store.sqlite` that is not this store's own.

    Opening a SQLite file read-write switches it to WAL and creates tables, which would alter
    another program's database. So: a symlink, a file that is not SQLite, a database not in WAL
    mode (this store always is) or one with other tables is a one-line error, and the file is
    read only with `immutable=1` (no lock, no -wal/-shm files created).
    """
    if not db.exists() and not db.is_symlink():
        return
    if db.is_symlink() or not db.is_file():
        raise InputError(f"{db}: not a regular file; refusing to open it as a ravenmem store")
    with open(db, "rb") as f:
        head = f.read(100)
    if not head:
        return  # an empty file: a store killed while it was being created
    if len(head) < 100 or not head.startswith(b"SQLite format 3\x00"):
        raise InputError(f"{db}: not a SQLite database, so not a ravenmem store; nothing was changed")
    if head[18] != 2 or head[19] != 2:
        raise InputError(
            f"{db}: a SQLite database not in WAL mode, so not a ravenmem store (another program's?); "
            "nothing was changed"
        )
    uri = f"file:{quote(str(db.resolve()))}?mode=ro&immutable=1"
    try:
        ro = sqlite3.connect(uri, uri=True)
        try:
            tables = {str(r[0]) for r in ro.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
        finally:
            ro.close()
    except sqlite3.DatabaseError as e:
        raise InputError(f"{db}: cannot be read as a ravenmem store ({e}); nothing was changed") from None
    if tables and not {"memories", "vectors", "meta"} <= tables:
        shown = ", ".join(sorted(tables)[:5])
        raise InputError(
            f"{db}: holds tables of another program ({shown}), not a ravenmem store; nothing was changed"
        )


@STORES.register("local")
def open_local(spec: str, *, dim: int, **kwargs: object) -> LocalStore:
    """`local:PATH` (or a plain folder path via `open_store`): the store files live in PATH."""
    if not spec:
        raise InputError("local store: a memory folder path is required (local:PATH)")
    unknown = sorted(set(kwargs) - set(_OPTIONS))
    if unknown:
        raise InputError(f"local store: unknown option(s) {unknown}; known: {sorted(_OPTIONS)}")
    return LocalStore(Path(spec).expanduser(), dim, **kwargs)  # type: ignore[arg-type]
