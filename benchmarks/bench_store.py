"""Store benchmark: latency of every tool, recall@10, bytes per memory, build and reopen time.

    PYTHONPATH=src python benchmarks/bench_store.py --sizes 10000,100000 [--dim 384] [--backend local]
    PYTHONPATH=src python benchmarks/bench_store.py --sizes 1000000 --dim 384 --backend local,milvus \\
        --milvus-uri 127.0.0.1:19530 --dir /tmp/bench         # side by side against a Milvus server
    nice -n 19 python benchmarks/bench_store.py --sizes 10000000 --dim 384 --dir /tmp/bench10m

The synthetic stream imitates a robot: it dwells at a place for 100-800 frames (the view a
random walk of unit vectors, so consecutive frames are near duplicates, drifting away over a
visit; the position a walk of 0.1 m per frame within 5 m of the place's spot on a 100 x 100 m
map), moves on, and revisits earlier places; one frame every 0.5 s, OCR text on 2 % of frames.
It is generated chunk by chunk (10M memories never sit in RAM) and deterministically, so a
second pass regenerates it for the ground truth: the exact top 10 of every query, with and
without each filter, by brute force over the generated vectors (one pass for all queries).
Queries are stored frames plus noise (the same place seen again).

The store is built with the bulk API (`add_many`, chunks of 50,000) unless `--build add`
(batches of 1,000 through `add`, as a live robot would). With `--dir`, stores are kept and
reused when they already hold N memories.
"""

from __future__ import annotations

import argparse
import resource
import shutil
import sys
import tempfile
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))

from ravenmem.store import Store, open_store  # noqa: E402
from ravenmem.types import Filter, MemoryRecord, Pose, Region  # noqa: E402

T0 = 1_700_000_000.0
WORDS = ["EXIT", "Room 101", "Kitchen", "Lab 3", "CAUTION", "Elevator", "Stairs", "Office 12"]
K = 10


def stream_arrays(n: int, dim: int, seed: int, batch: int) -> Iterator[tuple[int, np.ndarray, np.ndarray]]:
    """Yield (first index, unit embeddings (m, dim), positions (m, 2)) chunks of the stream.

    Places have a look (a centre in embedding space) and a spot on the map; a visit starts at
    a random offset from the place's look and drifts (random walk) frame by frame.
    """
    rng = np.random.default_rng(seed)
    n_places = max(4, n // 400)
    centres = rng.normal(size=(n_places, dim)).astype(np.float32)
    spots = rng.uniform(5, 95, (n_places, 2))
    emb_parts: list[np.ndarray] = []
    pos_parts: list[np.ndarray] = []
    have, start = 0, 0
    while start < n:
        m = min(batch, n - start)
        while have < m:  # whole visits, vectorised
            place, length = int(rng.integers(n_places)), int(rng.integers(100, 800))
            walk = rng.normal(size=dim).astype(np.float32) * 0.3
            steps = rng.standard_normal((length, dim), dtype=np.float32) * 0.04
            emb_parts.append(centres[place] + walk + np.cumsum(steps, axis=0))
            where = spots[place] + np.cumsum(rng.normal(0, 0.1, (length, 2)), axis=0)
            pos_parts.append(np.clip(where, spots[place] - 5, spots[place] + 5))
            have += length
        emb, pos = np.concatenate(emb_parts), np.concatenate(pos_parts)
        emb_parts, pos_parts, have = [emb[m:]], [pos[m:]], len(emb) - m
        yield start, emb[:m] / np.linalg.norm(emb[:m], axis=1, keepdims=True), pos[:m]
        start += m


def records(start: int, pos: np.ndarray) -> list[MemoryRecord]:
    return [
        MemoryRecord(
            id=-1,
            t=T0 + 0.5 * (start + i),
            pose=Pose(float(pos[i, 0]), float(pos[i, 1]), 0.0, 0.0),
            source="bench",
            frame_index=start + i,
            ocr_text=WORDS[(start + i) % len(WORDS)] if (start + i) % 50 == 0 else "",
        )
        for i in range(len(pos))
    ]


def stream(
    n: int, dim: int, seed: int, batch: int, work: Workload | None = None
) -> Iterator[tuple[list[MemoryRecord], np.ndarray]]:
    for start, emb, pos in stream_arrays(n, dim, seed, batch):
        if work is not None and not work.ready:
            work.collect(start, emb, pos)
        yield records(start, pos), emb


class Workload:
    """Queries, filters and their exact answers for a stream of n memories (ids 1..n)."""

    def __init__(self, n: int, dim: int, n_queries: int, cache: Path | None) -> None:
        self.n, self.dim, self.cache, self.ready, self.collected = n, dim, cache, False, False
        if cache is not None and cache.exists():
            z = np.load(cache)
            self.__dict__.update({k: z[k] for k in z.files})
            self.ready = True
            return
        rng = np.random.default_rng(1)
        self.pick = np.sort(rng.choice(n, n_queries, replace=False))
        self.spot_at = rng.integers(0, n, n_queries)
        self.q = np.empty((n_queries, dim), np.float32)
        self.spot = np.empty((n_queries, 2))
        self.noise = rng.normal(size=self.q.shape).astype(np.float32) * 0.5 / np.sqrt(dim)
        span = 0.5 * n
        self.w10 = T0 + span * rng.uniform(0, 0.9, n_queries)
        self.w1 = T0 + span * rng.uniform(0, 0.99, n_queries)
        self.times = T0 + 0.5 * rng.integers(0, n, n_queries)
        self.xy = rng.uniform(0, 100, (n_queries, 2))

    def collect(self, start: int, emb: np.ndarray, pos: np.ndarray) -> None:
        """Take the query frames and spots from a chunk of the stream (during the build)."""
        inside = (self.pick >= start) & (self.pick < start + len(emb))
        self.q[inside] = emb[self.pick[inside] - start]
        inside = (self.spot_at >= start) & (self.spot_at < start + len(emb))
        self.spot[inside] = pos[self.spot_at[inside] - start]
        self.collected = start + len(emb) >= self.n

    def finish(self) -> None:
        """Queries = frames plus noise; then the exact answers (one more pass over the stream)."""
        if self.ready:
            return
        if not self.collected:
            for chunk in stream_arrays(self.n, self.dim, 0, 50_000):
                self.collect(*chunk)
        q = self.q + self.noise
        self.q = q / np.linalg.norm(q, axis=1, keepdims=True)
        t = time.perf_counter()
        self._truth()
        print(
            f"ground truth for {len(self.q)} queries x 4 filters: {time.perf_counter() - t:.0f} s", flush=True
        )
        if self.cache is not None:
            np.savez(self.cache, **{k: v for k, v in self.__dict__.items() if isinstance(v, np.ndarray)})
        self.ready = True

    def filters(self, name: str) -> list[Filter | None]:
        span = 0.5 * self.n
        if name == "none":
            return [None] * len(self.q)
        if name == "w10":
            return [Filter(after=float(a), before=float(a + 0.1 * span)) for a in self.w10]
        if name == "w1":
            return [Filter(after=float(a), before=float(a + 0.01 * span)) for a in self.w1]
        return [Filter(region=Region(float(x), float(y), 10.0)) for x, y in self.spot]

    def _truth(self) -> None:
        """Exact top-K ids (1-based) per query and filter: one pass over the regenerated stream."""
        names = ("none", "w10", "w1", "r10")
        nq = len(self.q)
        best = {f: (np.zeros((nq, 0), np.int64), np.zeros((nq, 0), np.float32)) for f in names}
        span = 0.5 * self.n
        for start, emb, pos in stream_arrays(self.n, self.dim, 0, 50_000):
            ids = np.arange(start + 1, start + 1 + len(emb))
            t = T0 + 0.5 * np.arange(start, start + len(emb))
            scores = self.q @ emb.T  # (nq, m)
            masks = {
                "none": None,
                "w10": (t[None, :] >= self.w10[:, None]) & (t[None, :] <= self.w10[:, None] + 0.1 * span),
                "w1": (t[None, :] >= self.w1[:, None]) & (t[None, :] <= self.w1[:, None] + 0.01 * span),
                "r10": ((pos[None, :, :] - self.spot[:, None, :]) ** 2).sum(-1) <= 100.0,
            }
            for f in names:
                s = scores if masks[f] is None else np.where(masks[f], scores, -np.inf)
                all_ids = np.concatenate([best[f][0], np.broadcast_to(ids, s.shape)], axis=1)
                all_s = np.concatenate([best[f][1], s], axis=1)
                top = np.argpartition(-all_s, K - 1, axis=1)[:, :K]
                best[f] = (np.take_along_axis(all_ids, top, 1), np.take_along_axis(all_s, top, 1))
        for f in names:  # drop the -inf fillers where fewer than K memories pass the filter
            setattr(self, f"gt_{f}", np.where(np.isfinite(best[f][1]), best[f][0], 0))

    def recall(self, name: str, got: list[Any]) -> float:
        gt = getattr(self, f"gt_{name}")
        vals = []
        for row, hits in zip(gt, got, strict=False):
            want = {int(i) for i in row if i}
            if want:
                vals.append(len(want & {i for i, _ in hits}) / len(want))
        return float(np.mean(vals))


def measure(calls: list[Callable[[], object]]) -> tuple[float, float, float, list[Any]]:
    """p50 and p99 wall-clock ms, p50 CPU ms of the calling thread, and the results."""
    wall, cpu, out = [], [], []
    for call in calls:
        t, c = time.perf_counter(), time.thread_time()
        out.append(call())
        cpu.append((time.thread_time() - c) * 1000)
        wall.append((time.perf_counter() - t) * 1000)
    return float(np.percentile(wall, 50)), float(np.percentile(wall, 99)), float(np.median(cpu)), out


def peak_rss_gb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024**2


def open_backend(
    backend: str, n: int, args: argparse.Namespace, root: Path
) -> tuple[Store, Callable[[], Store]]:
    if backend == "local":
        opts: dict[str, Any] = {
            "nprobe": args.nprobe,
            "ann_threshold": args.ann_threshold,
            "codes": args.codes,
        }
        uri = str(root / f"local-{n}-{args.dim}")
    elif args.milvus_uri:
        opts, uri = {"collection": f"bench_{n}_{args.dim}"}, f"milvus://{args.milvus_uri}"
    else:
        opts, uri = {}, f"milvus://{root / f'milvus-{n}-{args.dim}.db'}"
    return open_store(uri, args.dim, **opts), lambda: open_store(uri, args.dim, **opts)


def build(store: Store, n: int, args: argparse.Namespace, work: Workload) -> str:
    if store.count() == n:
        return "reused"
    if store.count():
        raise SystemExit(f"{store}: holds {store.count()} memories, not {n}: remove it or use another --dir")
    t, cpu = time.perf_counter(), time.process_time()
    if args.build == "bulk":
        store.add_many(stream(n, args.dim, 0, 50_000, work), resume="bench")  # type: ignore[attr-defined]
    else:
        for recs, emb in stream(n, args.dim, 0, 1000, work):
            store.add(recs, emb)
        if hasattr(store, "wait_for_index"):
            store.wait_for_index()
    dt, cpu = time.perf_counter() - t, time.process_time() - cpu
    return (
        f"built ({args.build}) in {dt:.1f} s = {n / dt:,.0f} memories/s wall, "
        f"{cpu:.1f} s CPU (all threads) = {n / cpu:,.0f} memories/CPU-s"
    )


def bench(backend: str, n: int, args: argparse.Namespace, root: Path, work: Workload) -> dict[str, float]:
    store, reopen_fn = open_backend(backend, n, args, root)
    how = build(store, n, args, work)
    rss_build = peak_rss_gb()
    work.finish()
    store.close()
    t, cpu = time.perf_counter(), time.process_time()
    store = reopen_fn()
    reopen, reopen_cpu = time.perf_counter() - t, time.process_time() - cpu
    if hasattr(store, "wait_for_index"):
        store.wait_for_index()  # a rebuild the reopened store may have started: not while timing
    t = time.perf_counter()
    st = store.stats()
    first_stats = time.perf_counter() - t
    print(
        f"\n== {backend} store, N={n:,}, dim={args.dim}: index {st.get('index')} codes={st.get('codes')} "
        f"nlist={st.get('nlist')} nprobe={st.get('nprobe')} rerank={st.get('rerank')}; {how}; "
        f"reopened in {reopen:.2f} s ({reopen_cpu:.2f} s CPU; +{first_stats:.2f} s for the first stats: columns)"
    )
    if st.get("bytes"):
        print(
            f"bytes on disk: {st['bytes']:,} = {st['bytes_per_memory']:,.0f} B/memory; "
            f"index in RAM {st.get('index_ram_bytes', 0) / 1e9:.2f} GB"
        )
    nq = len(work.q)
    queries = list(work.q)
    for q in queries[:5]:  # warm up (pages, the k-d tree)
        store.search_vector(q, K, Filter(after=T0))
        store.nearest(50.0, 50.0, None, K)
    rows: list[tuple[str, float, float, float, str]] = []
    out: dict[str, float] = {"reopen_s": reopen, "bytes_per_memory": float(st.get("bytes_per_memory") or 0)}

    def row(name: str, key: str, calls: list[Callable[[], object]], truth: str | None = None) -> None:
        p50, p99, cpu, res = measure(calls)
        note = "" if truth is None else f"recall@10 {work.recall(truth, res):.3f}"
        rows.append((name, p50, p99, cpu, note))
        out[key] = p50
        if truth is not None:
            out[key + "_recall"] = work.recall(truth, res)

    if args.exact_queries:
        ne = min(nq, args.exact_queries)
        row(
            "vector search, exact scan",
            "exact",
            [lambda q=q: store.search_vector(q, K, exact=True) for q in queries[:ne]],
        )  # type: ignore[call-arg]
    row("vector search (text tool)", "ann", [lambda q=q: store.search_vector(q, K) for q in queries], "none")
    for label, name in (("time window 10%", "w10"), ("time window 1%", "w1"), ("region r=10 m", "r10")):
        filts = work.filters(name)
        calls = [lambda q=q, f=f: store.search_vector(q, K, f) for q, f in zip(queries, filts, strict=True)]
        row(f"vector search, {label}", name, calls, name)  # type: ignore[misc]
    if args.filter_budgets and hasattr(store, "filter_budget"):  # the 10 % window per budget
        default, calls = (
            store.filter_budget,
            [
                lambda q=q, f=f: store.search_vector(q, K, f)
                for q, f in zip(queries, work.filters("w10"), strict=True)
            ],
        )
        for fb in args.filter_budgets:
            store.filter_budget = fb
            row(f"  10% window, filter_budget {fb:g}", f"w10_fb{fb:g}", calls, "w10")  # type: ignore[misc]
        store.filter_budget = default
    row("by_time k=10", "by_time", [lambda t=t: store.by_time(float(t), K) for t in work.times])
    row("nearest k=10 (planar)", "nearest", [lambda p=p: store.nearest(p[0], p[1], None, K) for p in work.xy])
    row(
        "nearest k=10, radius 2 m",
        "nearest_r",
        [lambda p=p: store.nearest(p[0], p[1], None, K, radius=2.0) for p in work.xy],
    )
    words = [WORDS[i % len(WORDS)] for i in range(nq)]
    row("search_text (OCR) k=10", "ocr", [lambda w=w: store.search_text(w, K) for w in words])
    # live adds on top of the big store (a robot keeps running), then forget them again
    extra = list(stream(10_000, args.dim, 7, 1000))
    p50, p99, _, added = measure([lambda b=b: store.add(*b) for b in extra])
    rows.append(("add 1,000 (live, on top)", p50, p99, 0.0, ""))
    found = store.search_vector(extra[-1][1][-1], 1)[0][0] == added[-1][-1]
    t = time.perf_counter()
    gone = store.delete([i for ids in added for i in ids])  # type: ignore[attr-defined]
    rows.append(("delete those 10,000", (time.perf_counter() - t) * 1000, 0.0, 0.0, f"deleted {gone}"))
    print(f"{'tool':34s} {'p50 ms':>8s} {'p99 ms':>8s} {'CPU p50':>8s}")
    for name, a, b, c, note in rows:
        print(f"{name:34s} {a:8.2f} {b:8.2f} {c:8.2f}  {note}")
    print(
        f"live-added memory found by search: {found}; peak RSS: {rss_build:.2f} GB after the build, "
        f"{peak_rss_gb():.2f} GB at the end"
    )
    out["peak_rss_gb"] = peak_rss_gb()
    store.close()
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--sizes", default="10000,100000", help="comma-separated store sizes")
    ap.add_argument("--dim", type=int, default=384)
    ap.add_argument("--backend", default="local", help="local, milvus or both: local,milvus (side by side)")
    ap.add_argument("--milvus-uri", default=None, help="host:port of a Milvus server (default: Milvus Lite)")
    ap.add_argument("--queries", type=int, default=200)
    ap.add_argument("--exact-queries", type=int, default=0, help="also time this many exact scans")
    ap.add_argument("--build", choices=["bulk", "add"], default="bulk")
    ap.add_argument("--nprobe", type=int, default=32)
    ap.add_argument("--ann-threshold", type=int, default=50_000)
    ap.add_argument(
        "--filter-budgets",
        type=lambda v: [float(x) for x in v.split(",")],
        default=[],
        help="local: also time the 10%% window at each filter_budget, e.g. 4,6,8,10,16",
    )
    ap.add_argument("--codes", default="sq8", help="local IVF codes: sq8, flat or fp16")
    ap.add_argument(
        "--dir", type=Path, default=None, help="where to build and keep the stores, reused when complete"
    )
    args = ap.parse_args()
    root = args.dir or Path(tempfile.mkdtemp(prefix="bench_store_"))
    root.mkdir(parents=True, exist_ok=True)
    backends = args.backend.split(",")
    try:
        for n in (int(s) for s in args.sizes.split(",")):
            cache = root / f"truth-{n}-{args.dim}-{args.queries}.npz" if args.dir else None
            work = Workload(n, args.dim, args.queries, cache)
            results = {b: bench(b, n, args, root, work) for b in backends}
            if len(backends) > 1:
                print(f"\n-- side by side, N={n:,} (p50 ms; recall@10 in brackets)")
                keys = [k for k in results[backends[0]] if not k.endswith("_recall")]
                print(f"{'':22s}" + "".join(f"{b:>22s}" for b in backends))
                for k in keys:
                    cells = []
                    for b in backends:
                        v, r = results[b].get(k, float("nan")), results[b].get(k + "_recall")
                        cells.append(f"{v:,.2f}" + (f" ({r:.3f})" if r is not None else ""))
                    print(f"{k:22s}" + "".join(f"{c:>22s}" for c in cells))
    finally:
        if args.dir is None:
            shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
