""" "Where did I last see X?" at scale: the latest mode (`Memory.last_seen`) beside the text tool.

    PYTHONPATH=src python benchmarks/bench_last_seen.py [--sizes 100000,1000000] [--keep DIR]

The patrol memory of bench_changes.py (a 40 x 40 m loop, a keyframe every 0.5 m, dim 384; a mug
moved halfway, a kettle taken away at 80 %, a plant that never moves). For each size: p50 and
p90 of `search_text("mug", k=5)` and of `last_seen("mug")` over alternating calls, their ratio
(p50 over p50), and whether the latest mode's verdicts are right. `--keep DIR` keeps the built
memories there and reuses them on the next run (a million memories take minutes to build).

`--phases` also prints where a question's time goes (the latest mode's steps and the store calls
under them, wrapped with a clock: the sum of steps is the question). `--ram-vectors` measures a
store that reads vectors at RAM speed, as a memory-mapped vector file beside SQLite would: every
vector is loaded into RAM first and the store's exact re-scoring reads them from there; both
tools are timed again on it, side by side, so the ratio says whether such a file closes the gap.
`--floor` times, beside the text tool, the one store call every latest-mode question begins
with: the pool search (`search_vector`, k = the pool, 200, its 200 candidates re-scored
exactly, as `last_seen` asks for them) and nothing else. `--cached-records` times both tools
again with every record read once and then served from a dict: what answers that hold their
sightings without reading each one's record (ids, times and poses from RAM) could gain at most.
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from collections.abc import Sequence
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_changes import Labels, build_patrol, patrol, timings, verdicts  # noqa: E402

import ravenmem  # noqa: E402
from ravenmem.memory import changes, core  # noqa: E402
from ravenmem.store import _sql, local  # noqa: E402

STEPS = (
    "_pool",
    "seen_index",
    "_recent",
    "group_sightings",
    "grow",
    "merge",
    "revisits",
    "read_revisits",
    "_judge",
)
STORE_CALLS = ("search_vector", "_rescore", "_records", "by_time", "select")


def open_or_build(folder: Path, n: int, dim: int) -> tuple[ravenmem.Memory, float]:
    """The patrol memory of `n` keyframes in `folder` (built when absent); build seconds."""
    path = folder / f"patrol-{n}-{dim}.mem"
    if path.is_dir():
        things = patrol(min(n, 320), dim)[2]  # the things' directions depend on the seed only
        return ravenmem.open(path, embedder=Labels(dim, things)), 0.0
    t = time.perf_counter()
    mem = build_patrol(path, n, dim)
    return mem, time.perf_counter() - t


def phases(mem: ravenmem.Memory, reps: int) -> None:
    """Mean ms per question of each step of `Changes.last_seen` and of the store calls."""
    spent: dict[str, float] = {}
    calls: dict[str, int] = {}
    saved: list[tuple[object, str, object]] = [(changes, n, getattr(changes, n)) for n in STEPS]
    saved += [(local.LocalStore, n, getattr(local.LocalStore, n)) for n in STORE_CALLS]

    def clocked(name: str, fn: object) -> object:
        def run(*a: object, **kw: object) -> object:
            t = time.perf_counter()
            try:
                return fn(*a, **kw)  # type: ignore[operator]
            finally:
                spent[name] = spent.get(name, 0.0) + time.perf_counter() - t
                calls[name] = calls.get(name, 0) + 1

        return run

    for owner, name, fn in saved:
        setattr(owner, name, clocked(("store." if owner is local.LocalStore else "") + name, fn))
    try:
        t = time.perf_counter()
        for _ in range(reps):
            mem.last_seen("mug")
        total = (time.perf_counter() - t) / reps
    finally:
        for owner, name, fn in saved:
            setattr(owner, name, fn)
    print(
        f"  where a question's {1000 * total:.1f} ms go (mean of {reps}; steps, then store calls under them):"
    )
    for name, sec in sorted(spent.items(), key=lambda kv: (kv[0].startswith("store."), -kv[1])):
        print(f"    {name:<22} {1000 * sec / reps:6.1f} ms  {calls[name] / reps:5.0f} calls")


def floor(mem: ravenmem.Memory, reps: int) -> None:
    """The pool search alone (k = 200, the latest mode's first store call) beside the text tool."""
    q = np.asarray(mem.embedder.embed_texts(["mug"])[0], np.float32)
    st, pool = [], []
    for _ in range(reps):
        t = time.perf_counter()
        mem.search_text("mug", k=5)
        st.append(time.perf_counter() - t)
        t = time.perf_counter()
        k = changes.ChangeConfig().pool
        mem.store.search_vector(q, k, candidates=k)
        pool.append(time.perf_counter() - t)
    a, b = 1000 * float(np.median(st)), 1000 * float(np.median(pool))
    print(f"  the pool search alone: {b:.1f} ms p50 beside the text tool's {a:.1f} ms ({b / a:.1f}x)")


def ram_vectors(mem: ravenmem.Memory) -> None:
    """Re-score from every vector held in RAM (as a memory-mapped vector file would serve them)."""
    store = mem.store
    assert isinstance(store, local.LocalStore)
    top = int(store.select()[-1])
    table = np.zeros((top + 1, store.dim), np.float32)
    for ids, vecs in _sql.read_vectors(store._conn, 0, top):
        table[ids] = vecs

    def rescore(self: local.LocalStore, q: np.ndarray, ids: Sequence[int], k: int) -> list[tuple[int, float]]:
        got = np.asarray(ids, np.int64)
        return local._top(got, table[got] @ q[0], k) if len(got) else []

    local.LocalStore._rescore = rescore  # type: ignore[method-assign]


def cached_records() -> None:
    """Serve records from a dict after their first read (`Core.stored`), for both tools."""
    read = core.Core.stored
    held: dict[int, object] = {}

    def stored(self: core.Core, ids: Sequence[int], with_embeddings: bool = False) -> list[object]:
        if with_embeddings:
            return list(read(self, ids, with_embeddings=True))
        missing = [i for i in ids if i not in held]
        held.update((r.id, r) for r in (read(self, missing) if missing else []))
        return [held[i] for i in ids if i in held]

    core.Core.stored = stored  # type: ignore[method-assign,assignment]


def report(mem: ravenmem.Memory, n: int, build: float, reps: int, label: str = "") -> None:
    st, ls = timings(mem, reps)
    checks = verdicts(mem)
    p = lambda xs, q: 1000 * float(np.percentile(xs, q))  # noqa: E731
    print(
        f"{n:>9} {build:>8.1f} | {p(st, 50):>11.1f} {p(st, 90):>6.1f} | {p(ls, 50):>9.1f} "
        f"{p(ls, 90):>6.1f} | {p(ls, 50) / p(st, 50):>4.2f}x | " + "; ".join(checks) + label,
        flush=True,
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="100000,1000000")
    ap.add_argument("--dim", type=int, default=384)
    ap.add_argument("--reps", type=int, default=20)
    ap.add_argument("--keep", type=Path, default=None, help="build the memories here and reuse them")
    ap.add_argument("--phases", action="store_true", help="where a question's time goes, step by step")
    ap.add_argument("--ram-vectors", action="store_true", help="again with every vector read from RAM")
    ap.add_argument("--floor", action="store_true", help="the pool search alone beside the text tool")
    ap.add_argument("--cached-records", action="store_true", help="again with records served from a dict")
    args = ap.parse_args()
    folder = args.keep or Path(tempfile.mkdtemp(prefix="bench-last-seen-"))
    folder.mkdir(parents=True, exist_ok=True)
    print(f"latest mode vs text tool, patrol loop, dim {args.dim}; p50 / p90 ms over {args.reps} calls")
    print(
        f"{'memories':>9} {'build s':>8} | {'search_text':>11} {'p90':>6} | {'last_seen':>9} {'p90':>6} | ratio  | verdicts"
    )
    try:
        for n in [int(s) for s in args.sizes.split(",") if s]:
            mem, build = open_or_build(folder, n, args.dim)
            mem.last_seen("mug")  # warm: the first call reads the index and pages from disk
            report(mem, n, build, args.reps)
            if args.phases:
                phases(mem, args.reps)
            if args.floor:
                floor(mem, args.reps)
            if args.cached_records:
                saved = core.Core.stored
                cached_records()
                mem.last_seen("mug")
                report(mem, n, 0.0, args.reps, " (records served from a dict)")
                core.Core.stored = saved  # type: ignore[method-assign]
            if args.ram_vectors:
                ram_vectors(mem)
                mem.last_seen("mug")
                report(mem, n, 0.0, args.reps, " (vectors read from RAM)")
                if args.phases:
                    phases(mem, args.reps)
            mem.close()
    finally:
        if args.keep is None:
            shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main()
