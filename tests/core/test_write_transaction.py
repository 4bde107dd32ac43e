"""`fsio.write_transaction`: the one write transaction of the store and the groups file."""

from __future__ import annotations

import sqlite3
import threading
from pathlib import Path

import numpy as np
import pytest

from ravenmem.fsio import write_transaction
from ravenmem.store import _sql
from ravenmem.types import MemoryRecord, Pose


def _conn(path: Path) -> sqlite3.Connection:
    conn = sqlite3.connect(path, isolation_level=None, check_same_thread=False)
    conn.execute("CREATE TABLE t (v INTEGER)")
    return conn


def test_the_block_commits_and_another_connection_sees_it(tmp_path: Path) -> None:
    conn = _conn(tmp_path / "a.sqlite")
    with write_transaction(conn):
        conn.execute("INSERT INTO t VALUES (1)")
    other = sqlite3.connect(tmp_path / "a.sqlite")
    assert other.execute("SELECT v FROM t").fetchall() == [(1,)]
    assert not conn.in_transaction


@pytest.mark.parametrize("error", [ValueError("bad row"), KeyboardInterrupt()])
def test_an_error_in_the_block_rolls_back_and_is_raised(tmp_path: Path, error: BaseException) -> None:
    conn = _conn(tmp_path / "a.sqlite")
    with write_transaction(conn):
        conn.execute("INSERT INTO t VALUES (1)")
    with pytest.raises(type(error)), write_transaction(conn):
        conn.execute("INSERT INTO t VALUES (2)")
        raise error
    assert conn.execute("SELECT v FROM t").fetchall() == [(1,)]
    assert not conn.in_transaction
    with write_transaction(conn):  # the connection is usable again
        conn.execute("INSERT INTO t VALUES (3)")
    assert [v for (v,) in conn.execute("SELECT v FROM t ORDER BY v")] == [1, 3]


def test_a_second_writer_waits_for_the_first(tmp_path: Path) -> None:
    """BEGIN IMMEDIATE takes the write lock up front: a second writer queues behind the first
    (its busy timeout) instead of failing half-way through its block."""
    path = tmp_path / "a.sqlite"
    first = _conn(path)
    second = sqlite3.connect(path, isolation_level=None, timeout=30, check_same_thread=False)
    entered, release = threading.Event(), threading.Event()

    def hold() -> None:
        with write_transaction(first):
            first.execute("INSERT INTO t VALUES (1)")
            entered.set()
            release.wait(30)

    th = threading.Thread(target=hold)
    th.start()
    entered.wait(30)
    done = threading.Event()

    def write() -> None:
        with write_transaction(second):
            second.execute("INSERT INTO t VALUES (2)")
        done.set()

    tw = threading.Thread(target=write)
    tw.start()
    assert not done.wait(0.3)  # blocked behind the first writer's lock
    release.set()
    th.join(30)
    tw.join(30)
    assert done.is_set()
    assert [v for (v,) in second.execute("SELECT v FROM t ORDER BY v")] == [1, 2]


def test_set_poses_with_an_unknown_id_changes_nothing(tmp_path: Path) -> None:
    """The store's writes go through it: a batch with one bad id leaves every pose as it was."""
    conn = _sql.connect(str(tmp_path / "s.sqlite"))
    _sql.create_schema(conn)
    rec = MemoryRecord(id=0, t=1.0, pose=Pose(1.0, 2.0, 0.0, 0.5))
    _sql.insert(conn, [1], [rec], np.zeros((1, 4), np.float32))
    with pytest.raises(KeyError):
        _sql.set_poses(conn, [1, 99], [Pose(5.0, 5.0, 0.0, 0.0), Pose(6.0, 6.0, 0.0, 0.0)], {"k": "v"})
    assert conn.execute("SELECT x, y FROM memories WHERE id = 1").fetchone() == (1.0, 2.0)
    assert conn.execute("SELECT count(*) FROM meta WHERE key = 'k'").fetchone() == (0,)
