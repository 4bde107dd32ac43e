"""Crash safety: a process killed with SIGKILL mid-run loses no acknowledged write, and a
delete or bulk import it was in the middle of leaves whole batches (the old or the new state)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

import ravenmem
from ravenmem.store import open_store
from tests.store.store_helpers import batch_data

HERE = Path(__file__).resolve().parent
DIM, BATCH = 32, 40

CASES = {
    # exact index, saved every 120 rows: the kill lands between saves, so reopening adds a tail
    "local-flat": ({"save_min": 120, "save_fraction": 0.0}, 30),
    # crosses into IVF at 400 rows, the rebuild runs in a background thread when the kill comes
    "local-ivf": ({"ann_threshold": 400, "save_min": 200, "retrain_growth": 2.0}, 30),
    "milvus": ({}, 8),
}


def _uri(case: str, tmp_path: Path) -> str:
    if case.startswith("milvus"):
        pytest.importorskip("pymilvus")
        return f"milvus://{tmp_path / 'mem.db'}"
    return str(tmp_path / "mem")


def _run_and_kill(uri: str, options: dict[str, object], mode: str, n_acks: int) -> list[list[int]]:
    """Start the writer child, read `n_acks` acknowledgement lines, SIGKILL it."""
    env = dict(
        os.environ,
        PYTHONPATH=os.pathsep.join([str(Path(ravenmem.__file__).parents[1]), str(HERE.parents[1])]),
    )
    cmd = [
        sys.executable,
        str(HERE / "store_crash_writer.py"),
        uri,
        str(DIM),
        str(BATCH),
        json.dumps(options),
        mode,
    ]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    acked: list[list[int]] = []
    deadline = time.time() + 120
    assert proc.stdout is not None
    while len(acked) < n_acks and time.time() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        if line.strip() != "ready":
            acked.append([int(v) for v in line.split()])
    proc.send_signal(signal.SIGKILL)
    _, err = proc.communicate(timeout=30)
    assert len(acked) == n_acks, f"writer stopped early: {err[-2000:]}"
    return acked


@pytest.mark.parametrize("case", list(CASES))
def test_sigkill_keeps_acknowledged_batches(case: str, tmp_path: Path) -> None:
    options, n_acks = CASES[case]
    uri = _uri(case, tmp_path)
    acked = _run_and_kill(uri, options, "add", n_acks)
    if case != "milvus":
        # a killed background save leaves `.index.faiss.*.tmp`; opening the store removes such
        # files only once 2 s old (a younger one may be a live writer's, between creating and
        # locking it): give a kill that landed in a save that long
        temps = list((tmp_path / "mem").glob(".index.faiss.*.tmp"))
        if temps and time.time() - max(p.stat().st_mtime for p in temps) < 2.0:
            time.sleep(2.1)
    store = open_store(uri, DIM, **options)
    try:
        assert store.count() >= n_acks * BATCH
        for b, first, last in acked:
            recs, emb = batch_data(b, BATCH, DIM)
            got = store.get(list(range(first, last + 1)))
            assert [g.t for g in got] == [r.t for r in recs]
            for j in (0, BATCH // 2, BATCH - 1):
                top = store.search_vector(emb[j], 1)
                assert top[0][0] == first + j and top[0][1] == pytest.approx(1.0, abs=1e-5)
        if case != "milvus":
            assert not list((tmp_path / "mem").glob(".index.faiss.*.tmp")), "stale temporary index file"
            if case == "local-ivf":  # killed before or after the IVF was saved: IVF once rebuilt
                store.wait_for_index()  # type: ignore[attr-defined]
                assert store.stats()["index"] == "ivf"
        # the store keeps working after the crash
        recs, emb = batch_data(999, 5, DIM)
        ids = store.add(recs, emb)
        assert ids[0] > max(a[2] for a in acked)
        assert store.search_vector(emb[2], 1)[0][0] == ids[2]
        assert np.isfinite(store.stats()["t_max"])  # type: ignore[arg-type]
    finally:
        store.close()


DELETE_CASES = {
    "local-flat": {},
    "local-ivf": {"ann_threshold": 400},  # IVF with 8-bit codes; the index file predates the deletes
    "milvus": {},
}


@pytest.mark.parametrize("case", list(DELETE_CASES))
def test_sigkill_during_deletes_leaves_whole_batches(case: str, tmp_path: Path) -> None:
    """Batches deleted one call each: acknowledged ones are gone everywhere (count, get,
    search, select, nearest), the one the kill interrupted is either all gone or all there."""
    options = DELETE_CASES[case]
    uri = _uri(case, tmp_path)
    n_batches = 40  # the child adds them first (one process at a time may open Milvus Lite)
    n_acks = 6 if case == "milvus" else 15
    acked = [a[0] for a in _run_and_kill(uri, options, "delete", n_acks)]
    assert acked == list(range(n_acks))
    store = open_store(uri, DIM, **options)
    try:
        present = set(store.select().tolist())  # type: ignore[attr-defined]
        assert store.count() == len(present)
        for b in range(n_batches):
            ids = set(range(b * BATCH + 1, (b + 1) * BATCH + 1))
            if b < n_acks:
                assert not ids & present, f"acknowledged delete of batch {b} undone"
            else:
                assert ids <= present or not ids & present, f"batch {b} half deleted"
        for b in (0, n_acks - 1, n_batches - 1):
            _, emb = batch_data(b, BATCH, DIM)
            for j in (0, BATCH - 1):
                me, top = b * BATCH + j + 1, store.search_vector(emb[j], 1)[0][0]
                assert top in present and (top == me) == (me in present)
        near = store.nearest(0.0, 0.0, None, 50)
        assert {i for i, _ in near} <= present
        if case != "milvus":
            assert store.stats()["deleted"] >= n_acks * BATCH
    finally:
        store.close()


@pytest.mark.parametrize("case", ["local", "milvus"])
def test_sigkill_during_bulk_import_then_resume(case: str, tmp_path: Path) -> None:
    """A killed `add_many` leaves whole committed batches; rerunning the same import (same
    resume name) adds exactly the rest, in order, and everything is searchable."""
    options = {"ann_threshold": 300} if case == "local" else {}  # the import defers the index
    uri = _uri(case, tmp_path)
    acked = _run_and_kill(uri, options, "import", 4 if case == "milvus" else 12)
    store = open_store(uri, DIM, **options)
    try:
        n = store.count()
        assert n % BATCH == 0 and n >= len(acked) * BATCH
        total = n // BATCH + 3
        added = store.add_many((batch_data(b, BATCH, DIM) for b in range(total)), resume="crash")  # type: ignore[attr-defined]
        assert added == 3 * BATCH and store.count() == total * BATCH
        # every row once, in input order (Milvus may skip the ids a killed insert reserved)
        ts = [r.t for r in store.by_time(0.0, total * BATCH)]
        assert ts == [r.t for b in range(total) for r in batch_data(b, BATCH, DIM)[0]]
        for b in (0, len(acked), total - 1):
            recs, emb = batch_data(b, BATCH, DIM)
            top = store.search_vector(emb[7], 1)[0]
            assert top[1] == pytest.approx(1.0, abs=1e-5) and store.get([top[0]])[0].t == recs[7].t
        if case == "local":
            assert store.stats()["index"] == "ivf"
    finally:
        store.close()
