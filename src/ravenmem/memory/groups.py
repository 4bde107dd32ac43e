"""What a consolidated memory stands for: a sidecar table beside the store.

`ravenmem consolidate` replaces a run of near-duplicate memories by one of them (the
representative) that keeps how many memories it stands for and the time span they covered.
The store's schema is shared by backends that cannot take extra columns (Milvus 2.3 has a
fixed schema), so this lives in `lifelong.sqlite` in the memory folder, keyed by memory id:
`groups(rep, count, first_t, last_t)`.

Consolidating touches two databases (the store deletes the merged memories, this table records
the counts), so it is written as a small two-phase protocol that leaves either the old or the
new state after a crash, decided by the store's own one-transaction delete:

1. `begin`: the new rows go to `pending` with a batch row naming a *witness*, one of the ids
   about to be deleted (it exists now; only the writer deletes, and it holds the lock);
2. the store deletes the batch's ids (one transaction);
3. `commit`: the pending rows replace the live ones and the batch row goes.

A batch still pending is in effect exactly when its witness is gone from the store: readers
apply it on the fly, and the next writer (`recover`) commits it, or drops it when the store
never deleted. Rows of memories that were forgotten are dropped by `forget` (ids never repeat,
so a row left behind by a killed `forget` is never shown; `recover` prunes it). `drop_rows`
and `recover_groups` are what the writer handle (`ravenmem.memory.writer`) calls after a delete and when it
takes over after a crash.
"""

from __future__ import annotations

import logging
import sqlite3
import threading
import time
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np

from ..fsio import sqlite_reader, write_transaction
from ..store.base import Store
from .folder import GROUPS
from .recovery import set_aside

Group = tuple[int, float, float]  # (count, first_t, last_t)
log = logging.getLogger(__name__)

_SCHEMA = """
CREATE TABLE IF NOT EXISTS groups (
    rep INTEGER PRIMARY KEY, count INTEGER NOT NULL, first_t REAL NOT NULL, last_t REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS batches (
    id INTEGER PRIMARY KEY, witness INTEGER NOT NULL, drop_ids BLOB NOT NULL, created REAL NOT NULL
);
CREATE TABLE IF NOT EXISTS pending (
    batch INTEGER NOT NULL, rep INTEGER NOT NULL, count INTEGER NOT NULL,
    first_t REAL NOT NULL, last_t REAL NOT NULL, PRIMARY KEY (batch, rep)
);
"""


def exists(store: Store, mid: int) -> bool:
    """Whether the store holds memory `mid`."""
    try:
        store.get([int(mid)])
    except KeyError:
        return False
    return True


def _connect(path: Path, readonly: bool) -> sqlite3.Connection:
    if readonly:
        conn = sqlite_reader(path)  # mode=ro would leave -wal and -shm files behind
    else:
        conn = sqlite3.connect(path, check_same_thread=False, isolation_level=None, timeout=30.0)
        conn.execute("PRAGMA journal_mode=WAL")
        conn.execute("PRAGMA synchronous=FULL")
        conn.executescript(_SCHEMA)
    return conn


class GroupTable:
    """The writer's handle on `lifelong.sqlite` (created on first use)."""

    def __init__(self, folder: Path) -> None:
        self.path = Path(folder) / GROUPS
        try:
            self._conn = _connect(self.path, readonly=False)
        except sqlite3.DatabaseError as e:
            if getattr(e, "sqlite_errorname", "") not in ("SQLITE_NOTADB", "SQLITE_CORRUPT"):
                raise
            # garbage where the groups should be (a disk error, a hand): kept for a person,
            # and the writer starts a new table rather than refusing every write from now on
            for extra in (Path(f"{self.path}{x}") for x in ("-wal", "-shm")):
                if extra.exists():
                    set_aside(extra, "belongs to the groups table set aside", "groups table file")
            set_aside(
                self.path, f"not a SQLite database ({e}); consolidated counts start afresh", "groups table"
            )
            self._conn = _connect(self.path, readonly=False)

    def begin(self, rows: Sequence[tuple[int, int, float, float]], drop: np.ndarray) -> int:
        """Phase 1: record (rep, count, first_t, last_t) rows and the ids the store is about to
        delete (`drop`, non-empty, every one of them stored now); returns the batch id."""
        if len(drop) == 0:
            raise ValueError("a consolidation batch deletes at least one memory")
        ids = np.asarray(drop, np.int64)
        c = self._conn
        with write_transaction(c):
            cur = c.execute(
                "INSERT INTO batches (witness, drop_ids, created) VALUES (?, ?, ?)",
                (int(ids[0]), ids.tobytes(), time.time()),
            )
            batch = int(cur.lastrowid or 0)
            c.executemany(
                "INSERT INTO pending VALUES (?, ?, ?, ?, ?)",
                [(batch, int(r), int(n), float(a), float(b)) for r, n, a, b in rows],
            )
        return batch

    def commit(self, batch: int) -> None:
        """Phase 3: the store deleted the batch's ids; its rows become the live ones."""
        c = self._conn
        with write_transaction(c):
            row = c.execute("SELECT drop_ids FROM batches WHERE id = ?", (batch,)).fetchone()
            if row is not None:
                dropped = np.frombuffer(row[0], np.int64)
                _delete_reps(c, dropped)
                c.execute(
                    "INSERT OR REPLACE INTO groups SELECT rep, count, first_t, last_t FROM pending WHERE batch = ?",
                    (batch,),
                )
            c.execute("DELETE FROM pending WHERE batch = ?", (batch,))
            c.execute("DELETE FROM batches WHERE id = ?", (batch,))

    def abort(self, batch: int) -> None:
        """The store did not delete: the batch is forgotten, the old rows stay."""
        with write_transaction(self._conn):
            self._conn.execute("DELETE FROM pending WHERE batch = ?", (batch,))
            self._conn.execute("DELETE FROM batches WHERE id = ?", (batch,))

    def drop(self, ids: Iterable[int]) -> int:
        """Forget the rows of memories that were deleted; returns how many went."""
        arr = np.asarray(list(ids) if not isinstance(ids, np.ndarray) else ids, np.int64)
        with write_transaction(self._conn):
            return _delete_reps(self._conn, arr)

    def recover(self, store: Store) -> dict[str, int]:
        """After a killed writer: finish the batches the store applied, drop the others, and
        prune rows of memories that are gone. Returns the counts."""
        batches = self._conn.execute("SELECT id, witness FROM batches ORDER BY id").fetchall()
        done = aborted = 0
        for batch, witness in batches:
            if exists(store, witness):
                self.abort(int(batch))
                aborted += 1
            else:
                self.commit(int(batch))
                done += 1
        reps = np.array([r[0] for r in self._conn.execute("SELECT rep FROM groups")], np.int64)
        gone = reps[~np.isin(reps, store.select())] if len(reps) else reps
        pruned = self.drop(gone) if len(gone) else 0
        return {"committed": done, "aborted": aborted, "pruned": pruned}

    def close(self) -> None:
        self._conn.close()


def _delete_reps(conn: sqlite3.Connection, ids: np.ndarray) -> int:
    n = 0
    for s in range(0, len(ids), 900):
        chunk = [int(i) for i in ids[s : s + 900]]
        cur = conn.execute(f"DELETE FROM groups WHERE rep IN ({','.join('?' * len(chunk))})", chunk)
        n += max(cur.rowcount, 0)
    return n


class GroupView:
    """What readers see: rep -> (count, first_t, last_t), reloaded when the file changes.

    Costs one `stat` per call on a memory that was never consolidated, and one SQLite
    `PRAGMA data_version` otherwise (it changes when another connection wrote)."""

    def __init__(self, folder: Path) -> None:
        self.path = Path(folder) / GROUPS
        self._lock = threading.Lock()
        self._conn: sqlite3.Connection | None = None
        self._version: int | None = None
        self._rows: dict[int, Group] = {}

    def get(self, store: Store) -> dict[int, Group]:
        with self._lock:
            if self._conn is None:
                if not self.path.exists():
                    return {}
                self._conn = _connect(self.path, readonly=True)
            try:
                version = int(self._conn.execute("PRAGMA data_version").fetchone()[0])
                if version != self._version:
                    self._rows = _load(self._conn, store)
                    self._version = version
            except sqlite3.Error:  # a file still being created by the writer: nothing to show yet
                return {}
            return self._rows

    def invalidate(self) -> None:
        with self._lock:
            self._version = None

    def close(self) -> None:
        with self._lock:
            if self._conn is not None:
                self._conn.close()
                self._conn = None


def _load(conn: sqlite3.Connection, store: Store) -> dict[int, Group]:
    rows: dict[int, Group] = {
        int(r): (int(n), float(a), float(b))
        for r, n, a, b in conn.execute("SELECT rep, count, first_t, last_t FROM groups")
    }
    for batch, witness, drop in conn.execute(
        "SELECT id, witness, drop_ids FROM batches ORDER BY id"
    ).fetchall():
        if exists(store, witness):  # the store has not deleted this batch: not in effect
            continue
        for i in np.frombuffer(drop, np.int64).tolist():
            rows.pop(int(i), None)
        for r, n, a, b in conn.execute(
            "SELECT rep, count, first_t, last_t FROM pending WHERE batch = ?", (batch,)
        ):
            rows[int(r)] = (int(n), float(a), float(b))
    return rows


def annotate(hits: Iterable[object], groups: dict[int, Group]) -> None:
    """Set `count` and `span` on hits whose memory stands for several."""
    if not groups:
        return
    for h in hits:
        g = groups.get(h.memory.id)  # type: ignore[attr-defined]
        if g is not None:
            h.count, h.span = g[0], (g[1], g[2])  # type: ignore[attr-defined]


def drop_rows(folder: Path, ids: np.ndarray) -> None:
    """Drop the rows of memories the store just deleted (nothing to do on a memory without)."""
    if (folder / GROUPS).exists():
        table = GroupTable(folder)
        try:
            table.drop(ids)
        finally:
            table.close()


def recover_groups(folder: Path, store: Store) -> dict[str, int]:
    """Settle what a killed writer left in the table (nothing to do on a memory without)."""
    if not (folder / GROUPS).exists():
        return {}
    table = GroupTable(folder)
    try:
        done = table.recover(store)
    finally:
        table.close()
    if any(done.values()):
        log.info("%s: consolidation batches settled: %s", folder, done)
    return done
