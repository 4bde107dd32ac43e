""" "Where did I last see X?" at scale: the latest mode (`Memory.last_seen`) beside the text tool.

    PYTHONPATH=src python benchmarks/bench_last_seen.py [--sizes 100000,1000000] [--keep DIR]

The patrol memory of bench_changes.py (a 40 x 40 m loop, a keyframe every 0.5 m, dim 384; a mug
moved halfway, a kettle taken away at 80 %, a plant that never moves). For each size: p50 and
p90 of `search_text("mug", k=5)` and of `last_seen("mug")` over alternating calls, their ratio
(p50 over p50), and whether the latest mode's verdicts are right. `--keep DIR` keeps the built
memories there and reuses them on the next run (a million memories take minutes to build).
"""

from __future__ import annotations

import argparse
import shutil
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_changes import Labels, build_patrol, patrol, timings, verdicts  # noqa: E402

import ravenmem  # noqa: E402


def open_or_build(folder: Path, n: int, dim: int) -> tuple[ravenmem.Memory, float]:
    """The patrol memory of `n` keyframes in `folder` (built when absent); build seconds."""
    path = folder / f"patrol-{n}-{dim}.mem"
    if path.is_dir():
        things = patrol(min(n, 320), dim)[2]  # the things' directions depend on the seed only
        return ravenmem.open(path, embedder=Labels(dim, things)), 0.0
    t = time.perf_counter()
    mem = build_patrol(path, n, dim)
    return mem, time.perf_counter() - t


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--sizes", default="100000,1000000")
    ap.add_argument("--dim", type=int, default=384)
    ap.add_argument("--reps", type=int, default=20)
    ap.add_argument("--keep", type=Path, default=None, help="build the memories here and reuse them")
    args = ap.parse_args()
    folder = args.keep or Path(tempfile.mkdtemp(prefix="bench-last-seen-"))
    folder.mkdir(parents=True, exist_ok=True)
    print(f"latest mode vs text tool, patrol loop, dim {args.dim}; p50 / p90 ms over {args.reps} calls")
    print(
        f"{'memories':>9} {'build s':>8} | {'search_text':>11} {'p90':>6} | {'last_seen':>9} {'p90':>6} | ratio | verdicts"
    )
    try:
        for n in [int(s) for s in args.sizes.split(",") if s]:
            mem, build = open_or_build(folder, n, args.dim)
            mem.last_seen("mug")  # warm: the first call reads the index and pages from disk
            st, ls = timings(mem, args.reps)
            checks = verdicts(mem)
            mem.close()
            p = lambda xs, q: 1000 * float(np.percentile(xs, q))  # noqa: E731
            print(
                f"{n:>9} {build:>8.1f} | {p(st, 50):>11.1f} {p(st, 90):>6.1f} | {p(ls, 50):>9.1f} "
                f"{p(ls, 90):>6.1f} | {p(ls, 50) / p(st, 50):>4.1f}x | " + "; ".join(checks),
                flush=True,
            )
    finally:
        if args.keep is None:
            shutil.rmtree(folder, ignore_errors=True)


if __name__ == "__main__":
    main()
