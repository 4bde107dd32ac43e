"""How long `ravenmem` takes to start: before and after a change, side by side in one run.

Three commands, each a fresh Python process: `ravenmem --help`, `ravenmem search --help` and a
text search of the shipped sample (examples/tum_desk, ingested once here with the offline
embedder, no OCR). "before" runs a source tree exported from git (`--before REV`, default
5c4df6d: main before the lazy command loading) into a temporary folder; "after" runs this
checkout. Rounds alternate before/after so that a change in the machine's load hits both; the
bytecode of both trees is compiled first, and one untimed round warms the disk cache.
Reported: the median wall time and CPU time (user + system of the process) over --repeats.

    python benchmarks/bench_cli_start.py [--repeats 7] [--before 5c4df6d]
"""

from __future__ import annotations

import argparse
import compileall
import os
import resource
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from io import BytesIO
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SAMPLE = ROOT / "examples" / "tum_desk"


def export(rev: str, into: Path) -> Path:
    """The source tree of `rev` (git archive), unpacked under `into`; its `src` folder."""
    data = subprocess.run(["git", "-C", str(ROOT), "archive", rev, "src"], capture_output=True, check=True)
    with tarfile.open(fileobj=BytesIO(data.stdout)) as tar:
        tar.extractall(into, filter="data")
    return into / "src"


def timed(src: Path, args: list[str]) -> tuple[float, float]:
    """(wall s, CPU s) of one `python -m ravenmem.cli.main ARGS` with `src` first on the path."""
    env = {**os.environ, "PYTHONPATH": str(src)}
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    r = subprocess.run([sys.executable, "-m", "ravenmem.cli.main", *args], capture_output=True, env=env)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if r.returncode != 0:
        raise SystemExit(f"{args} failed with {src}: {r.stderr.decode()[-2000:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--before", default="5c4df6d", help="git revision timed as 'before'")
    opts = ap.parse_args()
    with tempfile.TemporaryDirectory(prefix="bench-cli-start-") as tmp:
        trees = {"before": export(opts.before, Path(tmp) / "before"), "after": ROOT / "src"}
        for src in trees.values():
            compileall.compile_dir(src, quiet=2)
        mem = Path(tmp) / "desk.mem"
        timed(trees["after"], ["ingest", str(SAMPLE), "-m", str(mem), "--no-ocr", "--thumb-size", "0"])
        commands = {
            "ravenmem --help": ["--help"],
            "ravenmem search --help": ["search", "--help"],
            'ravenmem search -m desk.mem "a keyboard"': ["search", "-m", str(mem), "a keyboard"],
        }
        runs: dict[tuple[str, str], list[tuple[float, float]]] = {}
        for rnd in range(opts.repeats + 1):  # round 0 warms the caches, untimed
            for name, args in commands.items():
                for which, src in trees.items():
                    wall_cpu = timed(src, args)
                    if rnd:
                        runs.setdefault((name, which), []).append(wall_cpu)
    load = os.getloadavg()
    print(f"median of {opts.repeats} fresh processes each; load average {load[0]:.2f} {load[1]:.2f}")
    print(f"{'command':44} {'before wall/CPU s':>18} {'after wall/CPU s':>18} {'CPU after/before':>17}")
    for name in commands:
        b, a = runs[(name, "before")], runs[(name, "after")]
        bw, bc = statistics.median(w for w, _ in b), statistics.median(c for _, c in b)
        aw, ac = statistics.median(w for w, _ in a), statistics.median(c for _, c in a)
        print(f"{name:44} {bw:8.2f} / {bc:6.2f}   {aw:8.2f} / {ac:6.2f}   {ac / bc:15.2f}x")


if __name__ == "__main__":
    main()
