"""What resuming costs on a large memory: the "already stored?" lookup ingest does (not a test).

Run: python benchmarks/bench_resume.py [--n 1000000] [--milvus 100000]
Builds a local store of N memories from 10 recordings (N/10 frames each; dim 8, since the lookup
never reads vectors), then measures, side by side in one run:
  - `source_frames` for a recording the memory has never seen (what every first ingest pays),
    and for one with N/10 stored frames (what resuming it pays, once per run);
  - `StoredFrames.find`, the per-frame membership test during the run;
  - the migration: building the source index on open of a memory made before it existed;
  - the same lookup with the index dropped (the full scan it avoids);
and the ratio of the lookup to one keyframe's ingest cost (~65 ms measured by bench_ingest.py).
Lookup times are CPU seconds of this process (best of several), not wall time.
With --milvus M, the same two lookups on a Milvus Lite store of M memories.
"""

from __future__ import annotations

import argparse
import sqlite3
import tempfile
import time
from pathlib import Path

import numpy as np

from ravenmem.ingest.pipeline import StoredFrames
from ravenmem.store import open_store
from ravenmem.types import Frame, MemoryRecord, Pose

DIM, SOURCES = 8, 10
KEYFRAME_S = 1 / 15.5  # docs/measured.md: ingest, offline embedder, no OCR


def fill(uri: str, n: int, batch: int = 20_000) -> None:
    store = open_store(uri, DIM)
    rng = np.random.default_rng(0)
    per = n // SOURCES
    for s in range(0, n, batch):
        ids = np.arange(s, min(n, s + batch))
        recs = [
            MemoryRecord(
                -1,
                t=1.7e9 + 0.1 * (i % per),
                pose=Pose(0.0, 0.0),
                source=f"tum:rec{i // per}@abc",
                frame_index=int(i % per),
            )
            for i in ids
        ]
        store.add(recs, rng.normal(size=(len(ids), DIM)).astype(np.float32) + 0.1)
    store.close()


def best(fn, repeat: int = 5) -> float:  # type: ignore[no-untyped-def]
    """Best of `repeat`, in CPU seconds of this process: on a shared machine wall time mostly
    measures the other jobs (SQLite reads are served from the page cache here)."""
    out = float("inf")
    for _ in range(repeat):
        t0 = time.process_time()
        fn()
        out = min(out, time.process_time() - t0)
    return out


def bench(uri: str, n: int, label: str) -> None:
    store = open_store(uri, DIM)
    try:
        t_new = best(lambda: store.source_frames("video:never-seen@000000000000"))
        t_old = best(lambda: store.source_frames("tum:rec3@abc"), repeat=3)
        print(
            f"{label} {n:,} memories: lookup of a new recording {t_new * 1e3:.2f} ms, "
            f"of one with {n // SOURCES:,} stored frames {t_old * 1e3:.0f} ms "
            f"({t_old / KEYFRAME_S:.1f} keyframes' ingest time)"
        )
        sf = StoredFrames(store, "tum:rec3@abc")
        frames = [
            Frame(np.zeros((1, 1, 3), np.uint8), 1.7e9 + 0.1 * i, Pose(0, 0), "tum:rec3@abc", i)
            for i in range(0, n // SOURCES, max(1, n // SOURCES // 10_000))
        ]
        sf.find(frames[0])
        t0 = time.process_time()
        hits = sum(sf.find(f) is not None for f in frames)
        per = (time.process_time() - t0) / len(frames)
        assert hits == len(frames)
        print(f"{label}: membership test per frame {per * 1e6:.1f} us ({per / KEYFRAME_S:.1e} of a keyframe)")
    finally:
        store.close()


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=1_000_000)
    ap.add_argument("--milvus", type=int, default=0, help="also a Milvus Lite store of this many memories")
    a = ap.parse_args()
    with tempfile.TemporaryDirectory() as d:
        folder = Path(d) / "big.mem"
        t0 = time.perf_counter()
        fill(str(folder), a.n)
        print(f"built a local store of {a.n:,} memories in {time.perf_counter() - t0:.0f} s")
        bench(str(folder), a.n, "local")
        db = folder / "store.sqlite"
        with sqlite3.connect(db) as conn:
            conn.execute("DROP INDEX memories_source")
            t0 = time.process_time()
            conn.execute("SELECT id, frame_index, t FROM memories WHERE source = 'video:x@0'").fetchall()
            scan = time.process_time() - t0
        print(f"local without the index (a memory made before it): lookup {scan * 1e3:.0f} ms (a full scan)")
        t0 = time.perf_counter()
        open_store(str(folder), DIM).close()
        print(
            f"migration: first open builds the index in {time.perf_counter() - t0:.1f} s wall (open included)"
        )
        if a.milvus:
            uri = f"milvus://{Path(d) / 'big.db'}"
            t0 = time.perf_counter()
            fill(uri, a.milvus, batch=5_000)
            print(f"built a Milvus Lite store of {a.milvus:,} memories in {time.perf_counter() - t0:.0f} s")
            bench(uri, a.milvus, "milvus lite")


if __name__ == "__main__":
    main()
