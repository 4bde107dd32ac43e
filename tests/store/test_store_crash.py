"""Crash safety: a writer killed with SIGKILL mid-run loses no acknowledged memory."""

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


@pytest.mark.parametrize("case", list(CASES))
def test_sigkill_keeps_acknowledged_batches(case: str, tmp_path: Path) -> None:
    options, n_acks = CASES[case]
    if case == "milvus":
        pytest.importorskip("pymilvus")
        uri = f"milvus://{tmp_path / 'mem.db'}"
    else:
        uri = str(tmp_path / "mem")
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
    ]
    proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    acked: list[tuple[int, int, int]] = []
    deadline = time.time() + 120
    assert proc.stdout is not None
    while len(acked) < n_acks and time.time() < deadline:
        line = proc.stdout.readline()
        if not line:
            break
        acked.append(tuple(int(v) for v in line.split()))  # type: ignore[arg-type]
    proc.send_signal(signal.SIGKILL)
    _, err = proc.communicate(timeout=30)
    assert len(acked) == n_acks, f"writer stopped early: {err[-2000:]}"

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
