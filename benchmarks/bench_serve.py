"""Service benchmark: a warm `ravenmem serve` against the same calls in-process, and under load.

    nice -n 19 python benchmarks/bench_serve.py [--memories 100000] [--seconds 60] [--clients 4]
        [--load both|none|core] [--ocr] [--keyframes SPEC] [--threads N]

1. Builds a memory of `--memories` synthetic memories (the robot-like stream of bench_store.py:
   precomputed unit vectors of the default embedder's dim 384, poses on a 100 x 100 m map, one
   frame every 0.5 s), so 100k memories take a minute, not hours. The manifest names the
   offline embedder, which embeds the text queries and the live frames.
2. Starts `ravenmem serve` on it (a subprocess, as a user would) and times warm text searches
   over HTTP (one keep-alive client, one request at a time) interleaved with the same
   `Memory.search_text` call in this process: p50/p99 and their ratio.
3. Load: five cameras add real camera frames (TUM fr1, or synthetic pictures without the data)
   at 5 per second in all (one frame per second each, each camera driving on at 0.3 m per frame)
   while `--clients` clients run text / time / position searches back to back for `--seconds`
   seconds: queries per second sustained, p50/p99 per kind, errors, and for the frames: how
   many were answered, how long each answer took (p50/p99, every frame: a frame the keyframe
   rules skip is answered too) and how many became memories. The service runs with its default
   keyframe rules (`--keyframes` to change them).
   `--load core` runs this phase beside a process that keeps one core busy (a stand-in for a
   robot's SLAM); `--load both` (the default) runs it twice, quiet then loaded, and prints
   both side by side. Then the service is stopped and the memory reopened: every stored frame
   must be there with its pose.

The machine these figures come from has 2 cores shared with other jobs; the script prints the
load average before and after, and CPU times next to wall-clock ones where it can.
"""

from __future__ import annotations

import argparse
import io
import json
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

import httpx
import numpy as np
from PIL import Image

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "src"))
sys.path.insert(0, str(ROOT / "benchmarks"))

from bench_store import stream  # noqa: E402

import ravenmem  # noqa: E402
from ravenmem.threads import share_cores  # noqa: E402

share_cores()  # the in-process side as the service (`ravenmem serve`) runs

TUM = ROOT.parent / "shared" / "data" / "tum_fr1_rpy"
QUERIES = [
    "a red backpack",
    "a computer keyboard",
    "a coffee mug",
    "an exit sign",
    "a office chair",
    "a laptop",
    "a whiteboard",
    "a potted plant",
    "a water bottle",
    "a door",
    "a printer",
    "stairs",
    "a fire extinguisher",
    "a person",
    "a monitor on a desk",
    "a book shelf",
    "a trash can",
    "a sofa",
    "a kitchen sink",
    "a window",
]


def pct(values: list[float], q: float) -> float:
    return float(np.percentile(values, q)) if values else float("nan")


def build(path: Path, n: int, dim: int, ocr: bool) -> float:
    """The synthetic memory; returns seconds taken."""
    t = time.perf_counter()
    mem = ravenmem.create(path, embedder="offline", ocr=ocr)
    if mem.dim != dim:
        raise SystemExit(f"the offline embedder has dim {mem.dim}, not {dim}")
    for recs, emb in stream(n, dim, seed=0, batch=10_000):
        mem.store.add(recs, emb)
    worker = getattr(mem.store, "_worker", None)
    if worker is not None:  # the IVF index trains in the background past 50k memories
        worker.join()
    mem.close()
    return time.perf_counter() - t


def start_service(
    path: Path, extra: list[str], env_extra: dict[str, str]
) -> tuple[subprocess.Popen[str], str]:
    env = dict(os.environ, PYTHONPATH=str(ROOT / "src"), **env_extra)
    env.pop("RAVENMEM_TOKEN", None)
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "ravenmem.cli.main",
            "serve",
            "--memory",
            str(path),
            "--port",
            "0",
            "--log-level",
            "warning",
            *extra,
        ],
        stdout=subprocess.PIPE,
        text=True,
        env=env,
    )
    assert proc.stdout is not None
    line = proc.stdout.readline()
    m = re.search(r"at (http://127\.0\.0\.1:\d+)/ ", line)
    if m is None:
        proc.kill()
        raise SystemExit(f"the service did not start: {line!r}")
    return proc, m.group(1)


def busy_core() -> subprocess.Popen[bytes]:
    """A process that keeps one core busy (a stand-in for SLAM), at the service's priority."""
    return subprocess.Popen([sys.executable, "-c", "while True: pass"])


def cpu_seconds(pid: int) -> float:
    """User + system CPU time of a process so far (Linux /proc), to see costs net of waiting."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def latency(path: Path, url: str, reps: int, pid: int) -> dict[str, float]:
    """Interleaved in-process and HTTP text searches (k=10), both warm.

    The in-process calls run as the service runs them: the models warmed up in the main thread,
    the searches in a worker thread. Torch runs its intra-op thread team only in the thread that
    first used it; on a loaded 2-core machine that team's spinning makes the same call from the
    main thread several times slower, which would flatter the service.
    """
    mem = ravenmem.open(path)
    mem.search_text("warm up", k=10)
    pool = ThreadPoolExecutor(1)

    def timed(q: str) -> tuple[float, float]:
        t, cpu = time.perf_counter(), time.process_time()
        mem.search_text(q, k=10)
        return (time.perf_counter() - t) * 1000, (time.process_time() - cpu) * 1000

    pool.submit(timed, "warm up").result()
    local, remote, local_cpu = [], [], []
    served_cpu = 0.0
    with httpx.Client(base_url=url, timeout=60) as c:
        c.get("/search/text", params={"q": "warm up", "k": 10}).raise_for_status()
        for r in range(reps):
            q = QUERIES[r % len(QUERIES)]
            wall, cpu = pool.submit(timed, q).result()
            local.append(wall)
            local_cpu.append(cpu)
            t, cpu = time.perf_counter(), cpu_seconds(pid)
            c.get("/search/text", params={"q": q, "k": 10}).raise_for_status()
            remote.append((time.perf_counter() - t) * 1000)
            served_cpu += cpu_seconds(pid) - cpu
    pool.shutdown()
    mem.close()
    return {
        "local_p50_ms": pct(local, 50),
        "local_p99_ms": pct(local, 99),
        "local_cpu_mean_ms": float(np.mean(local_cpu)),
        "http_server_cpu_mean_ms": 1000 * served_cpu / reps,
        "http_p50_ms": pct(remote, 50),
        "http_p99_ms": pct(remote, 99),
        "ratio_p50": pct(remote, 50) / pct(local, 50),
        "ratio_p99": pct(remote, 99) / pct(local, 99),
        "ratio_cpu": 1000 * served_cpu / reps / float(np.mean(local_cpu)),
    }


def frames(n: int) -> list[bytes]:
    """JPEG frames to add: real TUM pictures when the data is here, else synthetic ones."""
    files = sorted((TUM / "rgb").glob("*.jpg"))[::7][:n] if (TUM / "rgb").exists() else []
    if files:
        return [f.read_bytes() for f in files]
    rng = np.random.default_rng(1)
    out = []
    for _ in range(n):
        buf = io.BytesIO()
        Image.fromarray(rng.integers(0, 255, (480, 640, 3), dtype=np.uint8)).save(buf, "JPEG")
        out.append(buf.getvalue())
    return out


def load(
    url: str, seconds: float, clients: int, rate: float, t_last: float, pid: int, qps: float = 0.0
) -> dict[str, object]:
    """The load phase; `qps` > 0 paces the searching clients to that many queries per second in
    all (0: each client searches back to back, as fast as the service answers)."""
    stop = threading.Event()
    lock = threading.Lock()
    lat: dict[str, list[float]] = {"text": [], "time": [], "position": []}
    errors: list[str] = []
    acked: dict[int, float] = {}
    add_ms: list[float] = []  # every frame's answer, stored or skipped
    stored_ms: list[float] = []
    skipped_ms: list[float] = []
    skipped: dict[str, int] = {}
    pictures = frames(100)

    def camera(cam: int, cameras: int) -> None:
        """One of `cameras` cameras, each sending a frame every cameras/rate s in order (a frame
        older than its camera's last one would be skipped as non-monotonic)."""
        with httpx.Client(base_url=url, timeout=60) as c:
            n, start = 0, time.perf_counter() + cam / rate
            while not stop.is_set():
                time.sleep(max(0.0, start + n * cameras / rate - time.perf_counter()))
                i = n * cameras + cam
                n += 1
                x = 10.0 + 0.3 * n  # each camera's robot drives on 0.3 m per frame
                t = time.perf_counter()
                try:
                    r = c.post(
                        "/memories",
                        files={"image": ("f.jpg", pictures[i % len(pictures)], "image/jpeg")},
                        data={
                            "x": f"{x}",
                            "y": f"{10 + 15 * cam}",
                            "yaw": "0.1",
                            "t": f"{t_last + 1 + i / rate}",
                            "source": f"camera{cam}",
                        },
                    )
                    ms = (time.perf_counter() - t) * 1000
                    if r.status_code == 201:
                        with lock:
                            acked[r.json()["id"]] = x
                            add_ms.append(ms)
                            stored_ms.append(ms)
                    elif r.status_code == 200:
                        with lock:
                            add_ms.append(ms)
                            skipped_ms.append(ms)
                            why = str(r.json()["skipped"])
                            skipped[why] = skipped.get(why, 0) + 1
                    else:
                        errors.append(f"add {r.status_code}: {r.text[:100]}")
                except httpx.HTTPError as e:
                    errors.append(f"add: {e}")

    def searcher(seed: int) -> None:
        rng = random.Random(seed)
        kinds = ["text", "time", "position"]
        with httpx.Client(base_url=url, timeout=60) as c:
            n, start, every = seed, time.perf_counter(), clients / qps if qps > 0 else 0.0
            while not stop.is_set():
                if every:
                    time.sleep(max(0.0, start + (n - seed) * every - time.perf_counter()))
                kind = kinds[n % 3]
                n += 1
                if kind == "text":
                    params: dict[str, object] = {"q": rng.choice(QUERIES), "k": 10}
                elif kind == "time":
                    params = {"t": f"+{rng.uniform(0, 40_000):.1f}s", "k": 10}
                else:
                    params = {"x": rng.uniform(0, 100), "y": rng.uniform(0, 100), "k": 10}
                t = time.perf_counter()
                try:
                    r = c.get(f"/search/{kind}", params=params)
                    ok = r.status_code == 200
                    if not ok:
                        errors.append(f"{kind} {r.status_code}: {r.text[:100]}")
                except httpx.HTTPError as e:
                    ok = False
                    errors.append(f"{kind}: {e}")
                if ok:
                    with lock:
                        lat[kind].append((time.perf_counter() - t) * 1000)

    cams = max(1, round(rate))  # 5 frames/s: five cameras at 1 frame/s each
    threads = [threading.Thread(target=camera, args=(k, cams)) for k in range(cams)]
    threads += [threading.Thread(target=searcher, args=(s,)) for s in range(clients)]
    t0, cpu0 = time.perf_counter(), cpu_seconds(pid)
    for th in threads:
        th.start()
    time.sleep(seconds)
    stop.set()
    for th in threads:
        th.join()
    wall, served_cpu = time.perf_counter() - t0, cpu_seconds(pid) - cpu0
    every = [v for vals in lat.values() for v in vals]
    out: dict[str, object] = {
        "seconds": round(wall, 1),
        "queries": len(every),
        "queries_per_s": len(every) / wall,
        "p50_ms": pct(every, 50),
        "p99_ms": pct(every, 99),
        "service_cores": served_cpu / wall,
        "service_cpu_ms_per_query": 1000 * served_cpu / max(1, len(every)),
        "errors": len(errors),
        "error_samples": errors[:5],
        "frames_offered": round(rate * wall),
        "frames_answered": len(add_ms),
        "frames_answered_per_s": len(add_ms) / wall,
        "frames_within_1s": sum(v <= 1000 for v in add_ms),
        "frames_stored": len(acked),
        "frames_skipped": dict(skipped),
        "add_p50_ms": pct(add_ms, 50),
        "add_p99_ms": pct(add_ms, 99),
        "stored_p50_ms": pct(stored_ms, 50),
        "stored_p99_ms": pct(stored_ms, 99),
        "skipped_p50_ms": pct(skipped_ms, 50),
        "skipped_p99_ms": pct(skipped_ms, 99),
        "acked": acked,
    }
    for kind, vals in lat.items():
        out[f"{kind}_per_s"] = len(vals) / wall
        out[f"{kind}_p50_ms"] = pct(vals, 50)
        out[f"{kind}_p99_ms"] = pct(vals, 99)
    return out


def verify(path: Path, n: int, acked: dict[int, float]) -> dict[str, object]:
    with ravenmem.open(path) as mem:
        count = mem.count()
        found = {r.id: r.pose.x for r in mem.get(sorted(acked))} if acked else {}
    return {
        "count": count,
        "expected": n + len(acked),
        "all_acked_stored": found == acked and count == n + len(acked),
    }


def report(res: dict[str, object], args: argparse.Namespace, label: str) -> None:
    print(
        f"\nload ({label}): {args.clients} searching clients"
        f"{f' paced to {args.qps:g} queries/s' if args.qps else ' back to back'}"
        f" + cameras adding {args.rate:g} frames/s for {res['seconds']} s"
    )
    print(
        f"  queries/s   {res['queries_per_s']:.1f}  (text {res['text_per_s']:.1f}, time {res['time_per_s']:.1f}, "
        f"position {res['position_per_s']:.1f})   target >= 50"
    )
    for kind in ("text", "time", "position"):
        note = "   target p50 < 100 ms" if kind == "text" else ""
        print(f"  {kind:<9}   p50 {res[f'{kind}_p50_ms']:.1f} ms  p99 {res[f'{kind}_p99_ms']:.1f} ms{note}")
    print(f"  all         p50 {res['p50_ms']:.1f} ms  p99 {res['p99_ms']:.1f} ms")
    cores = float(res["service_cores"])  # type: ignore[arg-type]
    per_q = float(res["service_cpu_ms_per_query"])  # type: ignore[arg-type]
    print(f"  service     used {cores:.2f} cores, {per_q:.1f} ms CPU per query (adds included)")
    if "busy_cores" in res:
        print(f"  busy core   the stand-in for SLAM used {res['busy_cores']:.2f} cores")
    print(f"  errors      {res['errors']}  {res['error_samples'] if res['errors'] else ''}")
    answered, due = int(res["frames_answered"]), int(res["frames_offered"])  # type: ignore[call-overload]
    print(
        f"  frames      {answered} answered of {due} due ({res['frames_answered_per_s']:.2f}/s; each camera "
        f"waits for its answer), {res['frames_within_1s']} within 1 s; answer p50 {res['add_p50_ms']:.0f} ms "
        f"p99 {res['add_p99_ms']:.0f} ms (target p99 <= 1000 ms)"
    )
    print(
        f"  stored      {res['frames_stored']} (answer p50 {res['stored_p50_ms']:.0f} ms p99 "
        f"{res['stored_p99_ms']:.0f} ms); skipped {res['frames_skipped']} (answer p50 "
        f"{res['skipped_p50_ms']:.0f} ms p99 {res['skipped_p99_ms']:.0f} ms)"
    )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--memories", type=int, default=100_000)
    ap.add_argument("--dim", type=int, default=384)
    ap.add_argument("--reps", type=int, default=300, help="text searches timed each way")
    ap.add_argument("--seconds", type=float, default=60.0, help="length of each load phase")
    ap.add_argument("--clients", type=int, default=4, help="searching clients during the load phase")
    ap.add_argument("--rate", type=float, default=5.0, help="frames added per second during the load phase")
    ap.add_argument("--qps", type=float, default=0.0, help="pace the searches to this rate (0: back to back)")
    ap.add_argument(
        "--load",
        choices=("both", "none", "core"),
        default="both",
        help="the load phase quiet (none), beside a busy core (core), or both, one after the other",
    )
    ap.add_argument("--ocr", action="store_true", help="a memory that reads text in live frames")
    ap.add_argument("--keyframes", help="the service's --keyframes (default: its default rules)")
    ap.add_argument("--serve-args", default="", help="more `ravenmem serve` options, space-separated")
    ap.add_argument(
        "--service-env",
        action="append",
        default=[],
        help="KEY=VALUE in the service's environment (repeatable)",
    )
    ap.add_argument("--keep", type=Path, help="build the memory here and keep it (reused when present)")
    args = ap.parse_args()

    work = Path(tempfile.mkdtemp(prefix="bench-serve-"))
    path = args.keep or work / "synthetic.mem"
    print(
        f"load average before: {os.getloadavg()[0]:.1f} ({os.cpu_count()} cores); service: {' '.join(sys.argv[1:])}"
    )
    if not (path / "memory.json").exists():
        print(f"building {args.memories:,} memories (dim {args.dim}) ...", flush=True)
        print(f"  built in {build(path, args.memories, args.dim, args.ocr):.0f} s")
    with ravenmem.open(path) as mem:
        n0, t_last = mem.count(), mem.time_span()[1]
    extra = (["--keyframes", args.keyframes] if args.keyframes else []) + args.serve_args.split()
    env_extra = dict(kv.split("=", 1) for kv in args.service_env)
    proc, url = start_service(path, extra, env_extra)
    phases = {"both": ["quiet", "one core busy"], "none": ["quiet"], "core": ["one core busy"]}[args.load]
    results: dict[str, dict[str, object]] = {}
    acked: dict[int, float] = {}
    try:
        lat = latency(path, url, args.reps, proc.pid)
        print(f"\nwarm text search at {n0:,} memories (k=10, {args.reps} calls each way)")
        print(
            f"  in-process  p50 {lat['local_p50_ms']:.1f} ms  p99 {lat['local_p99_ms']:.1f} ms  "
            f"CPU {lat['local_cpu_mean_ms']:.1f} ms/call"
        )
        print(
            f"  HTTP        p50 {lat['http_p50_ms']:.1f} ms  p99 {lat['http_p99_ms']:.1f} ms  "
            f"service CPU {lat['http_server_cpu_mean_ms']:.1f} ms/call"
        )
        print(
            f"  ratio       p50 {lat['ratio_p50']:.2f}x  p99 {lat['ratio_p99']:.2f}x  CPU {lat['ratio_cpu']:.2f}x"
            "   (target p50 <= 3x)"
        )
        for k, label in enumerate(phases):
            busy = busy_core() if label != "quiet" else None
            try:
                b0 = cpu_seconds(busy.pid) if busy else 0.0
                t0 = time.perf_counter()
                # each phase starts later in time than everything the memory holds
                res = load(
                    url, args.seconds, args.clients, args.rate, t_last + 10_000 * (k + 1), proc.pid, args.qps
                )
                if busy is not None:
                    res["busy_cores"] = (cpu_seconds(busy.pid) - b0) / (time.perf_counter() - t0)
            finally:
                if busy is not None:
                    busy.kill()
                    busy.wait()
            got = res.pop("acked")
            assert isinstance(got, dict)
            acked.update(got)
            results[label] = res
            report(res, args, label)
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(120)
    check = verify(path, n0, acked)
    print(
        f"\nreopened      {check['count']:,} memories, expected {check['expected']:,}: "
        f"{'every stored frame there' if check['all_acked_stored'] else 'MISSING FRAMES'}"
    )
    print(f"load average after: {os.getloadavg()[0]:.1f}")
    print(json.dumps({"latency": lat, "load": results, "verify": check}, default=float))
    if args.keep is None:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
