"""SQLite schema and row mapping of the local store (the source of truth).

Metadata and vectors live in separate tables so that scans over metadata (time queries, the
columns loaded at open) never page through 2 KB vector blobs. OCR text is indexed, case- and
accent-folded, by a contentless FTS5 table (the text itself is stored once, in `memories`).
"""

from __future__ import annotations

import sqlite3
import sys
import time
from collections.abc import Iterator, Sequence
from typing import Any

import numpy as np

from ..errors import InputError
from ..fsio import write_transaction
from ..types import MAX_ANGLE, MAX_COORD, Filter, MemoryRecord, Pose
from ._common import POSE_COLUMNS, RECORD_COLUMNS, norm_text, pose_values, record_from, record_values

COLS = ", ".join(("id", *RECORD_COLUMNS))  # the `memories` table's columns, as SCHEMA creates them

SCHEMA = """
CREATE TABLE IF NOT EXISTS memories (
    id INTEGER PRIMARY KEY,
    t REAL NOT NULL,
    x REAL NOT NULL, y REAL NOT NULL, z REAL NOT NULL, yaw REAL NOT NULL,
    qx REAL, qy REAL, qz REAL, qw REAL,
    source TEXT NOT NULL DEFAULT '',
    frame_index INTEGER NOT NULL DEFAULT 0,
    image_path TEXT,
    ocr_text TEXT NOT NULL DEFAULT ''
);
CREATE INDEX IF NOT EXISTS memories_t ON memories (t, id);
CREATE TABLE IF NOT EXISTS vectors (id INTEGER PRIMARY KEY, v BLOB NOT NULL);
CREATE TABLE IF NOT EXISTS meta (key TEXT PRIMARY KEY, value TEXT NOT NULL);
CREATE TABLE IF NOT EXISTS deleted (seq INTEGER PRIMARY KEY, id INTEGER NOT NULL);
"""

# Indexes added after memories were already in use: (name, DDL), built on open when missing.
MIGRATIONS = [
    ("memories_source", "CREATE INDEX IF NOT EXISTS memories_source ON memories (source, frame_index, t)"),
]


def source_frames(conn: sqlite3.Connection, source: str) -> list[tuple[int, int, float]]:
    """(id, frame_index, t) of every memory from `source`: read from the covering index
    `memories_source` alone (no table rows), so it costs O(log n + matches)."""
    return conn.execute("SELECT id, frame_index, t FROM memories WHERE source = ?", (source,)).fetchall()


def connect(path: str, synchronous: str = "FULL") -> sqlite3.Connection:
    """A WAL connection usable from any thread (the store serialises access with a lock)."""
    conn = sqlite3.connect(path, check_same_thread=False, isolation_level=None, timeout=30.0)
    # 16 KB pages hold seven 2 KB vectors where 4 KB pages hold one (a no-op on an existing file)
    conn.execute("PRAGMA page_size=16384")
    conn.execute("PRAGMA journal_mode=WAL")
    conn.execute(f"PRAGMA synchronous={synchronous}")
    return conn


def create_schema(conn: sqlite3.Connection) -> str:
    """Create the tables once (and `migrate`); returns the FTS5 tokenizer in use (trigram when
    SQLite has it)."""
    conn.executescript(SCHEMA)
    migrate(conn)
    row = conn.execute("SELECT value FROM meta WHERE key = 'store.fts_tokenizer'").fetchone()
    if row:
        return str(row[0])
    tokenizer = "trigram"
    ddl = "CREATE VIRTUAL TABLE IF NOT EXISTS ocr USING fts5(folded, content='', tokenize='{}')"
    try:
        conn.execute(ddl.format(tokenizer))
    except sqlite3.OperationalError:
        tokenizer = "unicode61 remove_diacritics 2"
        conn.execute(ddl.format(tokenizer))
    conn.execute("INSERT OR REPLACE INTO meta VALUES ('store.fts_tokenizer', ?)", (tokenizer,))
    return tokenizer


def read_schema(conn: sqlite3.Connection, where: str) -> str:
    """What `create_schema` returns, for a reader (writes nothing): the FTS5 tokenizer in use;
    a database without the store's tables is a missing store."""
    tables = {str(r[0]) for r in conn.execute("SELECT name FROM sqlite_master WHERE type = 'table'")}
    if not {"memories", "vectors", "meta", "deleted", "ocr"} <= tables:
        raise InputError(f"{where}: store missing; nothing was changed (the store's tables are not there)")
    row = conn.execute("SELECT value FROM meta WHERE key = 'store.fts_tokenizer'").fetchone()
    return str(row[0]) if row else "trigram"


def migrate(conn: sqlite3.Connection) -> None:
    """Build the indexes a memory created by an older version lacks.

    Each CREATE INDEX is one SQLite transaction: a crash leaves the index complete or absent
    (built again on the next open), never half there. The check is a read, so opening an
    up-to-date memory writes nothing; a read-only memory that lacks an index opens anyway
    (queries fall back to a scan) and gets it on the first writable open."""
    have = {r[0] for r in conn.execute("SELECT name FROM sqlite_master WHERE type = 'index'")}
    for name, ddl in MIGRATIONS:
        if name not in have:
            try:
                conn.execute(ddl)
            except sqlite3.OperationalError as e:
                if "readonly" not in str(e):
                    raise


def record_row(rid: int, r: MemoryRecord) -> tuple[object, ...]:
    return (rid, *record_values(r))


def insert(
    conn: sqlite3.Connection,
    ids: Sequence[int],
    records: Sequence[MemoryRecord],
    emb: np.ndarray,
    meta: dict[str, str] | None = None,
) -> None:
    """Insert a batch in one transaction: all of it is durable on return, or none of it.
    `meta` keys are set in the same transaction (a bulk import's progress marker)."""
    with write_transaction(conn):
        conn.executemany(
            f"INSERT INTO memories ({COLS}) VALUES ({', '.join('?' * (1 + len(RECORD_COLUMNS)))})",
            [record_row(i, r) for i, r in zip(ids, records, strict=True)],
        )
        conn.executemany(
            "INSERT INTO vectors VALUES (?, ?)", [(i, e.tobytes()) for i, e in zip(ids, emb, strict=True)]
        )
        conn.executemany(
            "INSERT INTO ocr (rowid, folded) VALUES (?, ?)",
            [(i, norm_text(r.ocr_text)) for i, r in zip(ids, records, strict=True) if r.ocr_text],
        )
        if meta:
            conn.executemany("INSERT OR REPLACE INTO meta (key, value) VALUES (?, ?)", list(meta.items()))


def set_poses(
    conn: sqlite3.Connection, ids: Sequence[int], poses: Sequence[Pose], meta: dict[str, str]
) -> int:
    """New poses for stored memories, and `meta`, in one transaction; KeyError (and nothing
    changed) when an id is not stored."""
    sets = ", ".join(f"{c} = ?" for c in POSE_COLUMNS)
    with write_transaction(conn):
        n = 0
        for i, p in zip(ids, poses, strict=True):
            cur = conn.execute(f"UPDATE memories SET {sets} WHERE id = ?", (*pose_values(p), int(i)))
            if cur.rowcount != 1:
                raise KeyError(f"unknown memory id: {i}")
            n += 1
        conn.executemany("INSERT OR REPLACE INTO meta (key, value) VALUES (?, ?)", list(meta.items()))
    return n


def delete(conn: sqlite3.Connection, ids: np.ndarray) -> np.ndarray:
    """Delete the memories among `ids` (sorted, unique) in one transaction: rows, vectors,
    OCR index entries, and a line each in the deletion log that tells the index caches what
    to drop on open. Returns the ids that existed (and are now gone)."""
    with write_transaction(conn):
        gone = _delete_rows(conn, ids)
    return gone


def _delete_rows(conn: sqlite3.Connection, ids: np.ndarray) -> np.ndarray:
    gone: list[int] = []
    for s in range(0, len(ids), 900):
        chunk = [int(i) for i in ids[s : s + 900]]
        marks = ",".join("?" * len(chunk))
        rows = conn.execute(f"SELECT id, ocr_text FROM memories WHERE id IN ({marks})", chunk).fetchall()
        if not rows:
            continue
        have = [r[0] for r in rows]
        marks = ",".join("?" * len(have))
        # a contentless FTS5 table forgets a row when given the text it indexed
        conn.executemany(
            "INSERT INTO ocr (ocr, rowid, folded) VALUES ('delete', ?, ?)",
            [(i, norm_text(t)) for i, t in rows if t],
        )
        conn.execute(f"DELETE FROM memories WHERE id IN ({marks})", have)
        conn.execute(f"DELETE FROM vectors WHERE id IN ({marks})", have)
        conn.executemany("INSERT INTO deleted (id) VALUES (?)", [(i,) for i in have])
        gone += have
    return np.array(sorted(gone), np.int64)


_MAX_FLOAT = sys.float_info.max  # a finite number compares within +-this; inf and text do not
# A stored value no read can make a record of: a position or heading outside the ranges every
# write is checked against (`ravenmem.types`), a time that is not a finite number (times out of
# range stay: an earlier version stored some, and they are read and shown as numbers). What a
# disk error, another program or a writer from before the checks leaves: SQLite keeps NaN as
# NULL (refused by NOT NULL), so what is left is +-inf, a huge number, or text or a blob in a
# REAL column; each compares outside BETWEEN, so one scan of the table finds them all.
_SANE = (
    f"typeof(t) = 'real' AND t BETWEEN {-_MAX_FLOAT!r} AND {_MAX_FLOAT!r}"
    + "".join(f" AND typeof({c}) = 'real' AND {c} BETWEEN {-MAX_COORD!r} AND {MAX_COORD!r}" for c in "xyz")
    + f" AND typeof(yaw) = 'real' AND yaw BETWEEN {-MAX_ANGLE!r} AND {MAX_ANGLE!r}"
    + "".join(f" AND ({c} IS NULL OR {c} BETWEEN -2.0 AND 2.0)" for c in ("qx", "qy", "qz", "qw"))
)
ASIDE = "memories_aside"  # damaged rows, kept as they were (with their vector) for a person


def damaged(conn: sqlite3.Connection) -> np.ndarray:
    """Ids of the rows whose time, position, heading or orientation is out of range (sorted)."""
    rows = conn.execute(f"SELECT id FROM memories WHERE NOT ({_SANE})").fetchall()
    return np.array(sorted(r[0] for r in rows), np.int64)


def set_aside(conn: sqlite3.Connection, ids: np.ndarray) -> np.ndarray:
    """Move damaged rows (with their vectors) into the `memories_aside` table and delete them
    as `delete` does, in one transaction; returns the ids moved."""
    with write_transaction(conn):
        conn.execute(
            f"CREATE TABLE IF NOT EXISTS {ASIDE} AS SELECT *, NULL AS v, NULL AS set_aside FROM memories WHERE 0"
        )
        for s in range(0, len(ids), 900):
            chunk = [int(i) for i in ids[s : s + 900]]
            marks = ",".join("?" * len(chunk))
            conn.execute(f"DELETE FROM {ASIDE} WHERE id IN ({marks})", chunk)
            conn.execute(
                f"INSERT INTO {ASIDE} SELECT m.*, v.v, ? FROM memories m LEFT JOIN vectors v ON v.id = m.id "
                f"WHERE m.id IN ({marks})",
                [time.time(), *chunk],
            )
        gone = _delete_rows(conn, ids)
    return gone


def set_ocr_text(conn: sqlite3.Connection, ids: Sequence[int], texts: Sequence[str]) -> int:
    """Replace the OCR text of the memories among `ids` in one transaction, the FTS index
    with it; returns how many exist."""
    with write_transaction(conn):
        n = 0
        for i, text in zip(ids, texts, strict=True):
            row = conn.execute("SELECT ocr_text FROM memories WHERE id = ?", (int(i),)).fetchone()
            if row is None:
                continue
            if row[0]:  # a contentless FTS5 table forgets a row when given the text it indexed
                conn.execute(
                    "INSERT INTO ocr (ocr, rowid, folded) VALUES ('delete', ?, ?)",
                    (int(i), norm_text(row[0])),
                )
            conn.execute("UPDATE memories SET ocr_text = ? WHERE id = ?", (text, int(i)))
            if text:
                conn.execute("INSERT INTO ocr (rowid, folded) VALUES (?, ?)", (int(i), norm_text(text)))
            n += 1
    return n


def deletions(conn: sqlite3.Connection) -> tuple[int, int]:
    """(entries in the deletion log, highest id ever deleted)."""
    n, top = conn.execute("SELECT COALESCE(MAX(seq), 0), COALESCE(MAX(id), 0) FROM deleted").fetchone()
    return int(n), int(top)


def deleted_since(conn: sqlite3.Connection, seq: int) -> np.ndarray:
    """Ids deleted after the first `seq` entries of the deletion log, sorted."""
    rows = conn.execute("SELECT id FROM deleted WHERE seq > ?", (seq,)).fetchall()
    return np.unique(np.fromiter((r[0] for r in rows), np.int64, len(rows)))


def fetch_vectors(conn: sqlite3.Connection, ids: Sequence[int] | np.ndarray) -> dict[int, bytes]:
    """id -> float32 vector bytes for the ids that exist."""
    out: dict[int, bytes] = {}
    for s in range(0, len(ids), 900):
        chunk = [int(i) for i in ids[s : s + 900]]
        q = f"SELECT id, v FROM vectors WHERE id IN ({','.join('?' * len(chunk))})"
        out.update(conn.execute(q, chunk).fetchall())
    return out


def to_record(row: Sequence[Any], emb: bytes | None = None) -> MemoryRecord:
    return record_from(row[0], row[1:], None if emb is None else np.frombuffer(emb, np.float32).copy())


def where(filt: Filter | None, alias: str = "") -> tuple[str, list[float]]:
    """SQL conditions (joined by AND, '' when none) and parameters for a filter, applied exactly."""
    conds: list[str] = []
    args: list[float] = []
    if filt is not None:
        if filt.after is not None:
            conds.append(f"{alias}t >= ?")
            args.append(filt.after)
        if filt.before is not None:
            conds.append(f"{alias}t <= ?")
            args.append(filt.before)
        if filt.region is not None:
            r = filt.region
            conds.append(f"({alias}x - ?) * ({alias}x - ?) + ({alias}y - ?) * ({alias}y - ?) <= ?")
            args += [r.x, r.x, r.y, r.y, r.r * r.r]
    return " AND ".join(conds), args


def read_vectors(
    conn: sqlite3.Connection, after_id: int, upto_id: int, chunk: int = 50_000
) -> Iterator[tuple[np.ndarray, np.ndarray]]:
    """Yield (ids, float32 vectors) in id order for after_id < id <= upto_id, chunk by chunk."""
    last = after_id
    while True:
        rows = conn.execute(
            "SELECT id, v FROM vectors WHERE id > ? AND id <= ? ORDER BY id LIMIT ?", (last, upto_id, chunk)
        ).fetchall()
        if not rows:
            return
        ids = np.fromiter((r[0] for r in rows), np.int64, len(rows))
        vecs = np.frombuffer(b"".join(r[1] for r in rows), np.float32).reshape(len(rows), -1)
        yield ids, vecs
        last = int(ids[-1])
