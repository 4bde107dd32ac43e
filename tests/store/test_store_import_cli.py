"""`ravenmem import` end to end: a subprocess, as a user runs it (files in, exit codes out)."""

from __future__ import annotations

import csv
import json
import os
import re
import signal
import sqlite3
import subprocess
import sys
import time
from functools import partial
from pathlib import Path

import numpy as np
import pytest

import ravenmem
from ravenmem.errors import InputError
from ravenmem.store.files import read_batches
from tests.cli.helpers import run_cli
from tests.store.store_helpers import robot_stream

REPO = Path(__file__).resolve().parents[2]
DIM = 384  # the default (offline) embedder's


rm = partial(run_cli, timeout=600)


def write_files(
    folder: Path, n: int, kind: str = "csv", seed: int = 0
) -> tuple[Path, Path, np.ndarray, list[dict]]:
    emb = robot_stream(n, DIM, seed=seed, jump_every=300)
    rows = []
    for i in range(n):
        row: dict[str, object] = {
            "t": 1_700_000_000.0 + 0.5 * i,
            "x": float(i % 50),
            "y": float(i // 50),
            "z": 0.25,
        }
        if i % 3 == 0:  # a quaternion (yaw follows from it), else a yaw
            row.update(qx=0.0, qy=0.0, qz=float(np.sin(0.25)), qw=float(np.cos(0.25)))
        else:
            row["yaw"] = 0.1 * (i % 7)
        row.update(source="cam0", frame_index=10 * i, ocr_text="FIRE EXIT" if i % 97 == 0 else "")
        rows.append(row)
    vec = folder / "vectors.npy"
    np.save(vec, emb.astype(np.float16 if kind == "jsonl" else np.float32))
    meta = folder / f"meta.{kind}"
    if kind == "csv":
        cols = ["t", "x", "y", "z", "yaw", "qx", "qy", "qz", "qw", "source", "frame_index", "ocr_text"]
        with open(meta, "w", newline="") as f:
            w = csv.DictWriter(f, cols)
            w.writeheader()
            w.writerows(rows)
    elif kind == "jsonl":
        meta.write_text("".join(json.dumps(r) + "\n" for r in rows))
    else:
        pa = pytest.importorskip("pyarrow")
        import pyarrow.parquet as pq

        keys = list(dict.fromkeys(k for r in rows for k in r))  # from_pylist infers from row 0 only
        pq.write_table(pa.Table.from_pylist([{k: r.get(k) for k in keys} for r in rows]), meta)
    return vec, meta, emb, rows


def test_import_resume_again_and_search(tmp_path: Path) -> None:
    kind = "csv"
    vec, meta, emb, rows = write_files(tmp_path, 1_500, kind)
    mem = tmp_path / "m.mem"
    r = rm("import", str(vec), "--meta", str(meta), "--memory", str(mem), "--chunk", "400", "--json")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["added"] == 1_500 == out["memories_total"] and out["already_imported"] == 0
    r = rm("import", str(vec), "--meta", str(meta), "--memory", str(mem))
    assert r.returncode == 0 and "imported 0 of 1500" in r.stdout and "already imported" in r.stdout
    with ravenmem.open(mem) as m:
        got = m.get(range(1, 1_501))
        for g, row in zip(got, rows, strict=True):
            assert (g.t, g.pose.x, g.pose.y, g.pose.z, g.source, g.frame_index, g.ocr_text) == (
                row["t"],
                row["x"],
                row["y"],
                row["z"],
                row["source"],
                row["frame_index"],
                row["ocr_text"],
            )
            if "qz" in row:
                assert g.pose.quat is not None and g.pose.yaw == pytest.approx(0.5)
            else:
                assert g.pose.quat is None and g.pose.yaw == pytest.approx(row["yaw"])
        for i in (0, 700, 1_499):
            top = m.store.search_vector(emb[i], 1)[0]
            assert top[0] == i + 1 and top[1] == pytest.approx(1.0, abs=1e-2 if kind == "jsonl" else 1e-5)
        assert {h.memory.id for h in m.search_position(10.0, 3.0, k=1)} == {3 * 50 + 10 + 1}
        assert m.info()["ingests"][-1]["kind"] == "import"
    r = rm("import", str(vec), "--meta", str(meta), "--memory", str(mem), "--again", "--json")
    assert r.returncode == 0 and json.loads(r.stdout)["memories_total"] == 3_000


@pytest.mark.parametrize("kind", ["jsonl", "parquet"])
def test_metadata_formats_read_alike(tmp_path: Path, kind: str) -> None:
    """JSON Lines and Parquet give the same records as CSV (float16 vectors are widened)."""
    (tmp_path / "a").mkdir()
    (tmp_path / "b").mkdir()
    vec, meta, _, _ = write_files(tmp_path / "a", 700, "csv")
    vec2, meta2, _, _ = write_files(tmp_path / "b", 700, kind)
    n, dim, want = read_batches(vec, meta, chunk=300)
    n2, dim2, got = read_batches(vec2, meta2, chunk=300)
    assert (n, dim) == (n2, dim2) == (700, DIM)
    for (r1, e1), (r2, e2) in zip(want, got, strict=True):
        assert r1 == r2 and len(r1) in (300, 100)
        assert e2.dtype == np.float32 and np.allclose(e1, e2, atol=2e-3)


def test_import_bad_input_is_one_line(tmp_path: Path) -> None:
    vec, meta, _, _ = write_files(tmp_path, 50)
    mem = tmp_path / "m.mem"
    bad = tmp_path / "bad.csv"
    bad.write_text("t,x\n1,2\n")
    short = tmp_path / "short.csv"
    short.write_text(meta.read_text().rsplit("\n", 3)[0] + "\n")
    text = meta.read_text().splitlines()
    cells = text[7].split(",")
    cells[0] = "noon"
    (tmp_path / "val.csv").write_text("\n".join(text[:7] + [",".join(cells)] + text[8:]) + "\n")
    np.save(tmp_path / "ints.npy", np.ones((50, 8), np.int32))
    for args, match in [
        ((vec, bad), "missing column(s) y"),
        ((vec, short), "48 rows but"),
        ((tmp_path / "ints.npy", meta), "expected a 2-D float array"),
        ((meta, meta), ".npy"),
        ((vec, tmp_path / "meta.txt"), "no such metadata file"),
    ]:
        with pytest.raises(InputError, match=re.escape(match)):
            read_batches(*args)
    with pytest.raises(InputError, match="row 7: column t: not a number"):
        list(read_batches(vec, tmp_path / "val.csv")[2])
    # through the command: one line, exit 2, and the memory is left consistent
    r = rm("import", str(vec), "--meta", str(tmp_path / "val.csv"), "--memory", str(mem))
    assert r.returncode == 2 and "row 7: column t: not a number" in r.stderr and "Traceback" not in r.stderr
    np.save(tmp_path / "small.npy", np.ones((50, 8), np.float32))
    r = rm("import", str(tmp_path / "small.npy"), "--meta", str(meta), "--memory", str(mem))
    assert r.returncode == 2 and "holds 8-dim embeddings" in r.stderr and len(r.stderr.splitlines()) == 1
    with ravenmem.open(mem) as m:
        assert m.count() == 0 and m.dim == DIM  # the bad row was in the first chunk: nothing added


def test_killed_import_resumes_where_it_stopped(tmp_path: Path) -> None:
    n = 20_000
    vec, meta, emb, _ = write_files(tmp_path, n)
    mem = tmp_path / "m.mem"
    env = dict(os.environ, PYTHONPATH=str(REPO / "src"))
    args = ["import", str(vec), "--meta", str(meta), "--memory", str(mem), "--chunk", "1000", "--json"]
    proc = subprocess.Popen(
        [sys.executable, "-m", "ravenmem.cli.main", *args],
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    db, done = mem / "store.sqlite", 0
    deadline = time.time() + 300
    while time.time() < deadline and proc.poll() is None:
        if db.exists():
            try:
                with sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=1) as c:
                    done = c.execute("SELECT COUNT(*) FROM memories").fetchone()[0]
            except sqlite3.OperationalError:
                pass
        if done >= 4_000:
            break
        time.sleep(0.05)
    proc.send_signal(signal.SIGKILL)
    proc.communicate(timeout=30)
    assert 4_000 <= done < n, "the import finished before it could be killed"
    r = rm(*args)
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert (
        out["memories_total"] == n
        and out["already_imported"] >= 4_000
        and out["added"] == n - out["already_imported"]
    )
    with ravenmem.open(mem) as m:
        assert [g.t for g in m.get([1, n // 2, n])] == [
            1_700_000_000.0,
            1_700_000_000.0 + 0.5 * (n // 2 - 1),
            1_700_000_000.0 + 0.5 * (n - 1),
        ]
        for i in (0, 5_000, n - 1):
            assert m.store.search_vector(emb[i], 1)[0][0] == i + 1
