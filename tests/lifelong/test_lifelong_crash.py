"""Crash safety of `forget` and `consolidate`: SIGKILL at a random moment, then reopen.

Either every selected memory is gone or none is; a reader in between sees a consistent memory
(every stored memory has its thumbnail, the merged counts add up); after the next writer opens
it, no thumbnail, journal or temporary file is left over. The two-phase protocol of the group
table is also stepped through crash point by crash point, in process, and the moments when a
temporary file is written but not yet renamed (a few milliseconds of a run, which the random
kill hits only now and then) are hit on purpose.
"""

from __future__ import annotations

import os
import random
import shutil
import signal
import sqlite3
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import ravenmem
from ravenmem.fsio import is_temp_file
from ravenmem.memory.folder import GROUPS
from ravenmem.memory.groups import GroupTable
from tests.lifelong.lifelong_helpers import (
    T0,
    assert_consistent,
    env,
    make_runs,
    records,
    rm_json,
    writer_open,
)

ROUNDS = 3
HERE = Path(__file__).resolve().parent


@pytest.fixture(scope="module")
def big(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """2,000 memories with thumbnails: 40 runs of 50 near-duplicates."""
    return make_runs(
        tmp_path_factory.mktemp("crash") / "big.mem", runs=["red", "green", "blue", "yellow"] * 10, per_run=50
    )


def _kill_during(args: list[str], mem: Path, rng: random.Random) -> str:
    """Start the command; kill it a random moment after it wrote its thumbnail journal (or,
    one time in four, a random moment after it started). Returns how it ended."""
    proc = subprocess.Popen(
        [sys.executable, "-m", "ravenmem.cli.main", *args],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        env=env(),
    )
    if rng.random() < 0.25:
        time.sleep(rng.uniform(0.3, 2.5))
    else:
        deadline = time.time() + 120
        while not any(n.startswith("pending-thumbs-") for n in os.listdir(mem)):
            if proc.poll() is not None or time.time() > deadline:
                break
            time.sleep(0.001)
        time.sleep(rng.uniform(0.0, 0.1))
    proc.send_signal(signal.SIGKILL)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode in (0, -signal.SIGKILL), err[-2000:]
    return "finished" if proc.returncode == 0 else "killed"


def _represented(path: Path) -> tuple[set[int], int]:
    """Stored ids and how many memories they stand for, as a reader sees them right now."""
    with ravenmem.open(path) as m:
        info = m.info()
        ids = {r.id for r in m.all_records()}
        for r in m.all_records():  # a reader finds every stored memory's thumbnail
            assert m.image_file(r) is not None, r
    return ids, int(info.get("memories_represented", info["memories"]))


@pytest.mark.parametrize("round_", range(ROUNDS))
def test_forget_killed_at_a_random_moment(big: Path, tmp_path: Path, round_: int) -> None:
    seed = random.randrange(10**6)
    rng = random.Random(seed)
    mem = Path(shutil.copytree(big, tmp_path / "big.mem"))
    old = {r.id: r for r in records(mem)}
    cut = rng.randint(100, 1900)
    selected = {i for i, r in old.items() if r.t <= T0 + 10 * cut}
    how = _kill_during(["forget", "-m", str(mem), "--before", f"+{10 * cut}"], mem, rng)
    ids, n = _represented(mem)
    assert ids in (set(old), set(old) - selected), f"seed {seed} ({how}): a partial forget"
    assert n == len(ids)
    writer_open(mem)
    assert {r.id for r in records(mem)} == ids, f"seed {seed}: the next writer changed the memories"
    assert_consistent(mem, f"seed {seed} ({how})")


@pytest.mark.parametrize("round_", range(ROUNDS))
def test_consolidate_killed_at_a_random_moment(big: Path, tmp_path: Path, round_: int) -> None:
    seed = random.randrange(10**6)
    rng = random.Random(seed)
    mem = Path(shutil.copytree(big, tmp_path / "big.mem"))
    old = {r.id for r in records(mem)}
    budget = rng.choice([200, 400, 1000])
    plan = rm_json("consolidate", "-m", str(mem), "--budget", str(budget), "--dry-run")
    how = _kill_during(["consolidate", "-m", str(mem), "--budget", str(budget)], mem, rng)
    ids, n = _represented(mem)
    assert len(ids) in (len(old), plan["after"]), f"seed {seed} ({how}): {len(ids)} memories"
    assert n == 2000, f"seed {seed} ({how}): the merged memories are not all accounted for"
    writer_open(mem)
    assert {r.id for r in records(mem)} == ids and _represented(mem)[1] == 2000, f"seed {seed}"
    assert_consistent(mem, f"seed {seed} ({how})")
    with sqlite3.connect(mem / GROUPS) if (mem / GROUPS).exists() else _none() as conn:
        if conn is not None:
            assert conn.execute("SELECT COUNT(*) FROM batches").fetchone()[0] == 0, f"seed {seed}"
            assert conn.execute("SELECT COUNT(*) FROM pending").fetchone()[0] == 0, f"seed {seed}"


@pytest.mark.parametrize(("prefix", "merged"), [("pending-thumbs-", False), ("index.faiss", True)])
def test_consolidate_killed_before_a_rename_then_the_next_writer_at_once(
    tmp_path: Path, prefix: str, merged: bool
) -> None:
    """Deterministic: killed with a temporary file written and no longer locked (its thumbnail
    journal's, before anything changed; the vector index's, in the very last step), and the
    next writer opens at once, well inside the 2 s age guard on temporary files (a restart
    loop; the random test above when a kill lands there): it leaves no temporary file."""
    mem = make_runs(tmp_path / "m.mem")
    old = {r.id for r in records(mem)}
    args = ["consolidate", "-m", str(mem), "--budget", "6"]
    crash = subprocess.run(
        [sys.executable, str(HERE / "crash_at_rename.py"), prefix, *args],
        capture_output=True,
        text=True,
        env=env(),
        timeout=300,
    )
    assert crash.returncode == -signal.SIGKILL, crash.stderr[-2000:]
    assert [p for p in mem.iterdir() if is_temp_file(p) and p.name.startswith(f".{prefix}")]
    ids, n = _represented(mem)
    assert len(ids) == (6 if merged else len(old)) and n == len(old)
    writer_open(mem)
    assert {r.id for r in records(mem)} == ids
    assert_consistent(mem, prefix)


class _none:
    def __enter__(self) -> None:
        return None

    def __exit__(self, *_: object) -> None:
        return None


def _pending_batch(mem_path: Path, delete: bool) -> tuple[np.ndarray, int]:
    """Phase 1 of a consolidation of the first run (and phase 2 when `delete`), then the
    process "dies" (the handles are dropped without phase 3)."""
    with ravenmem.open(mem_path, writable=True) as m:
        run = [r for r in m.all_records() if r.t < T0 + 500][:50]
        rep, drop = run[25], np.array(sorted(r.id for r in run if r.id != run[25].id), np.int64)
        table = GroupTable(m.path)
        table.begin([(rep.id, 50, run[0].t, run[-1].t)], drop)
        if delete:
            m.store.delete(drop)
        table.close()
    return drop, rep.id


def test_group_protocol_crash_points(big: Path, tmp_path: Path) -> None:
    # killed after phase 1: the store did not delete, so the batch is not in effect
    a = Path(shutil.copytree(big, tmp_path / "a.mem"))
    drop, rep = _pending_batch(a, delete=False)
    ids, n = _represented(a)
    assert len(ids) == 2000 and n == 2000
    with ravenmem.open(a) as m:
        assert m.group(rep) is None
    writer_open(a)  # the next writer drops the batch
    with sqlite3.connect(a / GROUPS) as conn:
        assert conn.execute("SELECT COUNT(*) FROM batches").fetchone()[0] == 0
        assert conn.execute("SELECT COUNT(*) FROM groups").fetchone()[0] == 0
    assert len(records(a)) == 2000

    # killed after phase 2: the store deleted, so readers already see the new counts
    b = Path(shutil.copytree(big, tmp_path / "b.mem"))
    drop, rep = _pending_batch(b, delete=True)
    ids, n = _represented(b)
    assert len(ids) == 1951 and n == 2000
    with ravenmem.open(b) as m:
        assert m.group(rep) == (50, T0, T0 + 490) and m.time_span()[0] == T0
    writer_open(b)  # the next writer commits it, and deletes the merged memories' thumbnails
    with sqlite3.connect(b / GROUPS) as conn:
        assert conn.execute("SELECT COUNT(*) FROM batches").fetchone()[0] == 0
        assert conn.execute("SELECT rep, count FROM groups").fetchall() == [(rep, 50)]
    # the thumbnails of the deleted memories are still there: no journal was written in this
    # hand-made crash, so they are the one kind of leftover recovery cannot know about
    assert _represented(b)[1] == 2000
