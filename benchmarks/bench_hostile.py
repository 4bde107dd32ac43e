"""The hostile-input table's totals, and what eight large uploads at once cost the service.

1. The table of `tests/hardening/cases.py` (command lines, requests to a real `ravenmem serve`,
   MCP tool calls), run as the CI test runs it: tried / clear / traceback / silent / unclear, and
   data lost (the memories must still open, search and take writes, holding what they held).
2. Eight concurrent `POST /search/image` of one PNG that decodes to 36 megapixels (~120 KB on the
   wire, under the 40 MP limit of one picture), against `ravenmem serve` on a 12-memory colour
   memory: the service's peak RSS (VmHWM) before and after, and the answers (200 / 503).

`--compare SRC` runs the uploads against another source tree too (e.g. a checkout from before
the hardening), side by side in one run, and prints the ratio of the peak RSS (the table runs on
this checkout only: its prepared files use this checkout's `ravenmem`).

    PYTHONPATH=src:. python benchmarks/bench_hostile.py [--compare /path/to/old/src]
"""

from __future__ import annotations

import argparse
import io
import json
import os
import subprocess
import sys
import tempfile
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def table(src: Path) -> dict[str, object]:
    """The table's totals with `src` on PYTHONPATH (the test files are this checkout's)."""
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(src), str(ROOT)]))
    r = subprocess.run(
        [sys.executable, "-c", "from tests.hardening.runner import main; main()"],
        env=env,
        capture_output=True,
        text=True,
        cwd=ROOT,
    )
    lines = r.stdout.strip().splitlines()
    if r.returncode != 0 or not lines:
        sys.exit(f"the table did not run with {src}: {r.stderr[-2000:]}")
    out: dict[str, object] = json.loads(lines[0])
    out["not clear"] = lines[1:]
    return out


def big_png() -> bytes:
    from PIL import Image

    buf = io.BytesIO()
    Image.new("RGB", (6000, 6000), (200, 30, 30)).save(buf, format="PNG", optimize=True)
    return buf.getvalue()


def peak_rss_mb(pid: int) -> float:
    for line in Path(f"/proc/{pid}/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) / 1024
    return float("nan")


def uploads(src: Path, data: bytes, n: int = 8) -> dict[str, object]:
    """`n` concurrent image searches of `data` against a service running `src`."""
    import httpx

    sys.path.insert(0, str(ROOT))
    from tests.server.conftest import make_memory

    with tempfile.TemporaryDirectory() as tmp:
        make_memory(Path(tmp) / "m.mem").close()
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(src), str(ROOT)]))
        proc = subprocess.Popen(
            [
                sys.executable,
                str(ROOT / "tests/server/serve_color.py"),
                "serve",
                "-m",
                f"{tmp}/m.mem",
                "--port",
                "0",
                "--log-level",
                "error",
                "--max-upload-mb",
                "64",
            ],
            stdout=subprocess.PIPE,
            stderr=subprocess.DEVNULL,
            text=True,
            env=env,
        )
        try:
            assert proc.stdout is not None
            url = proc.stdout.readline().split(" at ")[1].split("/ ")[0].rstrip("/")
            idle = peak_rss_mb(proc.pid)

            def one(_: int) -> int:
                files = {"image": ("big.png", data, "image/png")}
                return httpx.post(url + "/search/image", files=files, timeout=600).status_code

            start = time.perf_counter()
            with ThreadPoolExecutor(n) as pool:
                codes = list(pool.map(one, range(n)))
            wall = time.perf_counter() - start
            return {
                "idle_mb": round(idle),
                "peak_mb": round(peak_rss_mb(proc.pid)),
                "codes": codes,
                "s": round(wall, 1),
            }
        finally:
            proc.kill()
            proc.wait()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--compare", type=Path, help="another src folder, run side by side")
    ap.add_argument("--skip-table", action="store_true", help="only the uploads")
    ap.add_argument("--table-only", action="store_true", help="only the table")
    a = ap.parse_args()
    srcs = {"this": ROOT / "src"} | ({"compare": a.compare} if a.compare else {})
    data = b"" if a.table_only else big_png()
    size = "" if a.table_only else f"upload: {len(data) / 1024:.0f} KB PNG, 6000x6000 = 36 MP; "
    print(f"{size}load average {os.getloadavg()[0]:.1f}")
    results: dict[str, dict[str, object]] = {}
    for name, src in srcs.items():
        if not a.skip_table and name == "this":  # the table's files need this checkout's ravenmem
            t = table(src)
            print(f"{name}: table {json.dumps({k: v for k, v in t.items() if k != 'not clear'})}")
            for line in t["not clear"][:50]:  # type: ignore[index]
                print(f"  {line[:220]}")
        if a.table_only:
            return
        results[name] = uploads(src, data)
        print(f"{name}: 8 concurrent 36 MP image searches: {json.dumps(results[name])}")
    if a.compare:
        ratio = float(results["compare"]["peak_mb"]) / float(results["this"]["peak_mb"])  # type: ignore[arg-type]
        print(f"peak RSS, compare / this: {ratio:.2f}x")


if __name__ == "__main__":
    main()
