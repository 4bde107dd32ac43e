"""Cold `ravenmem` commands against `python -c "import torch"`, side by side in one run.

Each repeat starts fresh Python processes, in turn: `import torch` (the floor for anything that
runs a torch model), `ravenmem search "text"` (text encoder only), `ravenmem search --image`
(the image network), `ravenmem search --time` and `ravenmem info` (no model at all). Reported: the median wall time of each over --repeats, and the
ratio of the text search to `import torch` (target: <= 2.5x). The memory searched is built first
from 6 TUM frames (`--keyframes all`, no OCR); one untimed round warms the disk cache and the
label-bank cache, so "cold" means a new process, not a new machine.

`--compare SRC` also times the text and image searches with another source tree on PYTHONPATH
(e.g. a checkout from before a change), in the same rounds.

    PYTHONPATH=src python benchmarks/bench_cli.py [--repeats 7] [--compare /path/to/old/src]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT.parent / "shared" / "data" / "tum_fr1_rpy"
TARGET = 2.5


def run(cmd: list[str], src: Path) -> float:
    env = dict(os.environ, PYTHONPATH=str(src))
    t = time.perf_counter()
    r = subprocess.run(cmd, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t
    if r.returncode != 0:
        sys.exit(f"{' '.join(cmd)} failed ({r.returncode}): {r.stderr.strip()[-500:]}")
    return wall


def build(folder: Path, mem: Path) -> None:
    listed = [
        ln.split() for ln in (DATA / "rgb.txt").read_text().splitlines() if ln and not ln.startswith("#")
    ]
    rows = ["file,t,x,y,z,yaw"]
    folder.mkdir()
    for i, (stamp, rel) in enumerate(listed[:6]):
        (folder / f"f{i}.jpg").write_bytes((DATA / rel).read_bytes())
        rows.append(f"f{i}.jpg,{stamp},0.0,0.0,0.0,{0.6 * i}")
    (folder / "poses.csv").write_text("\n".join(rows) + "\n")
    cli = [sys.executable, "-m", "ravenmem.cli.main"]
    run([*cli, "ingest", str(folder), "-m", str(mem), "--keyframes", "all", "--no-ocr"], ROOT / "src")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=7)
    ap.add_argument("--compare", type=Path, help="another src folder to time the text search with")
    a = ap.parse_args()
    if not (DATA / "rgb.txt").exists():
        sys.exit(f"TUM data not found at {DATA}")
    src = ROOT / "src"
    py = sys.executable
    with tempfile.TemporaryDirectory() as d:
        mem = Path(d) / "bench.mem"
        build(Path(d) / "frames", mem)
        cli = [py, "-m", "ravenmem.cli.main"]
        cases: dict[str, tuple[list[str], Path]] = {
            "python -c 'import torch'": ([py, "-c", "import torch"], src),
            'ravenmem search "text"': ([*cli, "search", "-m", str(mem), "a computer keyboard"], src),
            "ravenmem search --image": (
                [*cli, "search", "-m", str(mem), "--image", str(mem.parent / "frames" / "f0.jpg")],
                src,
            ),
            "ravenmem search --time": ([*cli, "search", "-m", str(mem), "--time", "+1s"], src),
            "ravenmem info": ([*cli, "info", "-m", str(mem)], src),
        }
        if a.compare:
            for name in ('ravenmem search "text"', "ravenmem search --image"):
                cases[f"{name} ({a.compare})"] = (cases[name][0], a.compare)
        for cmd, where in cases.values():  # warm-up: disk cache, label bank
            run(cmd, where)
        times: dict[str, list[float]] = {name: [] for name in cases}
        for _ in range(a.repeats):
            for name, (cmd, where) in cases.items():
                times[name].append(run(cmd, where))
    load = os.getloadavg()[0]
    print(
        f"{a.repeats} rounds, median wall seconds (load average {load:.1f} at the end, {os.cpu_count()} CPUs):"
    )
    base = statistics.median(times["python -c 'import torch'"])
    for name, ts in times.items():
        med = statistics.median(ts)
        print(
            f"  {name:<60} {med:6.2f} s  ({med / base:.2f}x import torch; min {min(ts):.2f}, max {max(ts):.2f})"
        )
    ratio = statistics.median(times['ravenmem search "text"']) / base
    print(
        f"cold text search / import torch: {ratio:.2f}x (target <= {TARGET}x): {'OK' if ratio <= TARGET else 'MISSED'}"
    )


if __name__ == "__main__":
    main()
