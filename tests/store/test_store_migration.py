"""Memories created before the source index existed get it on open, and keep working."""

from __future__ import annotations

import sqlite3
from pathlib import Path

import numpy as np
import pytest

from ravenmem.store import _sql, open_store
from tests.store.store_helpers import make_records, robot_stream

DIM = 16


def _plan(db: Path) -> str:
    with sqlite3.connect(db) as conn:
        rows = conn.execute("EXPLAIN QUERY PLAN SELECT id, frame_index, t FROM memories WHERE source = 'x'")
        return " ".join(str(r[-1]) for r in rows)


def test_local_store_without_source_index_gets_it_on_open(tmp_path: Path) -> None:
    folder = tmp_path / "old.mem"
    store = open_store(str(folder), DIM)
    recs = make_records(50)
    ids = store.add(recs, robot_stream(50, DIM))
    store.close()
    with sqlite3.connect(folder / "store.sqlite") as conn:  # what an older version created
        conn.execute("DROP INDEX memories_source")
    assert "memories_source" not in _plan(folder / "store.sqlite")

    store = open_store(str(folder), DIM)
    try:
        assert "COVERING INDEX memories_source" in _plan(folder / "store.sqlite")
        got = store.source_frames("cam1")
        want = sorted((r.frame_index, i) for r, i in zip(recs, ids) if r.source == "cam1")
        assert list(zip(got.frame_index.tolist(), got.ids.tolist())) == want
        assert store.count() == 50 and store.search_vector(robot_stream(50, DIM)[7], 1)[0][0] == ids[7]
    finally:
        store.close()


def test_migration_on_a_read_only_connection_is_skipped_not_fatal(tmp_path: Path) -> None:
    """A memory on read-only media that predates the index still opens (the lookup scans)."""
    folder = tmp_path / "ro.mem"
    store = open_store(str(folder), DIM)
    store.add(make_records(20), robot_stream(20, DIM))
    store.close()
    db = folder / "store.sqlite"
    with sqlite3.connect(db) as conn:
        conn.execute("DROP INDEX memories_source")
    conn = sqlite3.connect(f"file:{db}?mode=ro", uri=True)
    try:
        _sql.migrate(conn)
        assert len(_sql.source_frames(conn, "cam0")) == 13
    finally:
        conn.close()
    assert "memories_source" not in _plan(db)


def test_milvus_collection_without_source_index_gets_it_on_open(tmp_path: Path) -> None:
    pytest.importorskip("pymilvus")
    uri = f"milvus://{tmp_path / 'old.db'}"
    store = open_store(uri, DIM)
    recs = make_records(30)
    ids = store.add(recs, robot_stream(30, DIM))
    client = store.client  # type: ignore[attr-defined]
    client.release_collection("ravenmem")
    client.drop_index("ravenmem", "source")
    assert client.list_indexes("ravenmem", field_name="source") == []
    store.close()

    store = open_store(uri, DIM)
    try:
        assert store.client.list_indexes("ravenmem", field_name="source")  # type: ignore[attr-defined]
        got = store.source_frames("cam0")
        want = sorted((r.frame_index, i) for r, i in zip(recs, ids) if r.source == "cam0")
        assert list(zip(got.frame_index.tolist(), got.ids.tolist())) == want
        assert np.all(np.diff(got.frame_index) >= 0)
    finally:
        store.close()
