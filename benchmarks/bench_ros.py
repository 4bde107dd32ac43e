"""The ROS 2 node on a real graph (not a test; prints numbers).

Run: nice -n 5 python benchmarks/bench_ros.py [--seconds 60] [--keyframes all] [--domain 131] [--http]
(needs the `ros` extra and `ravenmem ros setup`; the TUM recording from $RAVENMEM_TUM_DATA).

Three processes over Fast DDS on this host: `ravenmem ros run` on a new memory (the default
embedder), the TUM freiburg1_rpy frames (640x480 rgb8) published as sensor_msgs/Image with
nav_msgs/Odometry at `--rate` (30 Hz) for `--seconds` (the recording played again when longer),
and a client here that calls /ravenmem/search every 0.5 s and /ravenmem/ask (offline) every 2 s
while the frames stream, beside a plain subscriber with the node's QoS. Prints: frames offered,
what the plain subscriber received, what the node received and what it counted lost in
transport (sequence gaps; and what DDS reported), stored, skipped by reason; keyframes stored
per second (until the last was stored); service latencies (n, p50, p99, max, the first call);
the node's exit code on SIGTERM. Every frame offered must be received or counted lost, and
every frame received stored or skipped with a reason.

`--tf`: the node's cost per /tf message (the intake's bounded TF buffer, 100 Hz odom -> base_link
for 60 s of stamps with 30 s kept, one image posed per 3 messages), no graph.

`--http`: the same stream side by side into `ravenmem serve` over HTTP instead: each frame a
`POST /memories` (the JPEG file, the ground-truth pose) sent at 30 Hz by 8 client threads, the
searches as `GET /search/text` and `POST /ask`; the same figures.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from tests.ros.rosgraph import Client, graph_env, launch_node, stop, wait_for  # noqa: E402


def pct(xs: list[float], q: float) -> float:
    if not xs:
        return float("nan")
    s = sorted(xs)
    return s[min(len(s) - 1, int(round(q * (len(s) - 1))))]


def latency(xs: list[float]) -> dict[str, Any]:
    """Calls made, p50, p99 and the slowest in seconds, and the first call's (a cold start shows)."""
    return {
        "n": len(xs),
        "p50": round(pct(xs, 0.5), 3),
        "p99": round(pct(xs, 0.99), 3),
        "max": round(max(xs, default=float("nan")), 3),
        "first": round(xs[0], 3) if xs else None,
    }


def call_loop(search: Any, ask: Any, done: threading.Event, out: dict[str, list[float]]) -> None:
    """A search every 0.5 s and a question every 2 s until `done`, each call's seconds in `out`."""
    last_ask = 0.0
    while not done.is_set():
        t = time.perf_counter()
        search()
        out["search"].append(time.perf_counter() - t)
        if time.monotonic() - last_ask >= 2.0:
            last_ask = time.monotonic()
            t = time.perf_counter()
            ask()
            out["ask"].append(time.perf_counter() - t)
        done.wait(0.5)


def ros_calls(client: Client, done: threading.Event, out: dict[str, list[float]]) -> None:
    from ravenmem_msgs.srv import Ask, Search

    call_loop(
        lambda: client.call(Search, "/ravenmem/search", Search.Request(tool="text", query="a desk", k=5)),
        lambda: client.call(Ask, "/ravenmem/ask", Ask.Request(question="where is the desk?")),
        done,
        out,
    )


def run_tf(messages: int = 6000) -> dict[str, Any]:
    """Seconds per TF message through `FrameIntake.transforms` (see the module docstring)."""
    import math
    from types import SimpleNamespace as NS

    from ravenmem.ros.intake import FrameIntake
    from ravenmem.ros.params import NodeSettings

    class Writer:  # the intake's writer, which only counts: the TF cost alone
        def submit(self, *a: Any, **k: Any) -> Any:
            from concurrent.futures import Future

            f: Future[Any] = Future()
            f.set_result(NS(id=1, skipped=None))
            return f

    intake = FrameIntake(Writer(), NodeSettings(odom_topic=""))  # type: ignore[arg-type]
    static = NS(transforms=[_tf("map", "odom", 0.0, 0.0)])
    intake.transforms(static, 0.0, True)
    t0 = 1_700_000_000.0
    per = []
    for i in range(messages):
        t = t0 + i * 0.01
        msg = NS(transforms=[_tf("odom", "base_link", t, math.sin(i / 100))])
        start = time.perf_counter()
        intake.transforms(msg, t, False)
        per.append(time.perf_counter() - start)
    size = len(intake.tf.moving["base_link"]) if intake.tf is not None else 0  # type: ignore[union-attr]
    return {
        "messages": messages,
        "p50_ms": round(pct(per, 0.5) * 1e3, 4),
        "p99_ms": round(pct(per, 0.99) * 1e3, 4),
        "max_ms": round(max(per) * 1e3, 4),
        "samples_kept": size,
    }


def _tf(parent: str, child: str, t: float, x: float) -> Any:
    from types import SimpleNamespace as NS

    sec = int(t)
    return NS(
        header=NS(frame_id=parent, stamp=NS(sec=sec, nanosec=int((t - sec) * 1e9))),
        child_frame_id=child,
        transform=NS(translation=NS(x=x, y=0.0, z=0.0), rotation=NS(x=0.0, y=0.0, z=0.0, w=1.0)),
    )


def run_http(data: Path, frames: int, rate: float, keyframes: str) -> dict[str, Any]:
    """The stream into `ravenmem serve` over HTTP (see the module docstring)."""
    import re
    from concurrent.futures import ThreadPoolExecutor

    import httpx
    import numpy as np

    from tests.ros.ros_pub import tum

    rgb, gt = tum(data, frames)
    with tempfile.TemporaryDirectory() as tmp:
        env = dict(os.environ, PYTHONPATH=str(REPO / "src"))
        env.pop("RAVENMEM_TOKEN", None)
        cmd = [
            sys.executable,
            "-m",
            "ravenmem.cli.main",
            "serve",
            "--memory",
            f"{tmp}/http.mem",
            "--create",
            "--port",
            "0",
            "--log-level",
            "warning",
            *(["--keyframes", keyframes] if keyframes else []),
        ]
        proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, text=True, env=env)
        assert proc.stdout is not None
        m = re.search(r"at (http://127\.0\.0\.1:\d+)/ ", proc.stdout.readline())
        assert m is not None, "the service did not start"
        url = m.group(1)
        outcome: dict[str, int] = {}
        lock = threading.Lock()

        def post(t: float, path: Path) -> None:
            row = gt[min(int(np.searchsorted(gt[:, 0], t)), len(gt) - 1)]
            form = {
                "x": row[1],
                "y": row[2],
                "z": row[3],
                "qx": row[4],
                "qy": row[5],
                "qz": row[6],
                "qw": row[7],
                "t": t,
                "source": "http",
            }
            try:
                r = httpx.post(
                    f"{url}/memories",
                    data={k: str(v) for k, v in form.items()},
                    files={"image": ("f.jpg", path.read_bytes(), "image/jpeg")},
                    timeout=120,
                )
                key = (
                    "stored"
                    if r.status_code == 201
                    else (
                        f"skipped: {r.json().get('skipped')}"
                        if r.status_code == 200
                        else f"HTTP {r.status_code}"
                    )
                )
            except httpx.HTTPError as e:
                key = f"error: {type(e).__name__}"
            with lock:
                outcome[key] = outcome.get(key, 0) + 1

        lat: dict[str, list[float]] = {"search": [], "ask": []}
        done = threading.Event()

        def calls() -> None:
            with httpx.Client(base_url=url, timeout=120) as c:
                call_loop(
                    lambda: c.get("/search/text", params={"q": "a desk", "k": 5}),
                    lambda: c.post("/ask", json={"question": "where is the desk?"}),
                    done,
                    lat,
                )

        caller = threading.Thread(target=calls, daemon=True)
        caller.start()
        t0 = next_t = time.monotonic()
        with ThreadPoolExecutor(8) as pool:
            for t, path in rgb:
                pool.submit(post, t, path)
                next_t += 1.0 / rate
                time.sleep(max(0.0, next_t - time.monotonic()))
            streamed = time.monotonic() - t0
        drained = time.monotonic() - t0
        done.set()
        caller.join(60)
        proc.send_signal(signal.SIGTERM)
        proc.wait(120)
    stored = outcome.get("stored", 0)
    return {
        "frames_offered": len(rgb),
        "seconds_streamed": round(streamed, 1),
        "answered": sum(outcome.values()),
        "stored": stored,
        "outcomes": outcome,
        "keyframes_per_s": round(stored / drained, 2),
        "seconds_until_stored": round(drained, 1),
        "search_s": latency(lat["search"]),
        "ask_s": latency(lat["ask"]),
        "service_exit": proc.returncode,
    }


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--seconds", type=float, default=60.0)
    ap.add_argument("--rate", type=float, default=30.0)
    ap.add_argument("--keyframes", default="all", help="the node's keyframe rule ('' for the defaults)")
    ap.add_argument("--domain", type=int, default=131)
    ap.add_argument("--http", action="store_true", help="the same stream into `ravenmem serve` over HTTP")
    ap.add_argument("--tf", action="store_true", help="the cost of one /tf message (no graph)")
    args = ap.parse_args()
    if args.tf:
        print(json.dumps(run_tf(), indent=2))
        return
    data = Path(os.environ.get("RAVENMEM_TUM_DATA") or REPO.parent / "shared" / "data" / "tum_fr1_rpy")
    frames = int(args.seconds * args.rate)
    if args.http:
        print(json.dumps(run_http(data, frames, args.rate, args.keyframes), indent=2))
        return
    print(json.dumps(run_ros(data, frames, args.rate, args.keyframes, args.domain), indent=2))


def run_ros(data: Path, frames: int, rate: float, keyframes: str, domain: int) -> dict[str, Any]:
    """The stream into `ravenmem ros run` on a real graph (see the module docstring)."""
    from diagnostic_msgs.msg import DiagnosticArray
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image

    from ravenmem.ros.params import NodeSettings

    with tempfile.TemporaryDirectory() as tmp:
        mem, log = Path(tmp) / "bench.mem", Path(tmp) / "node.log"
        ros_args = ["-p", "image_qos:=reliable", "-p", "image_transport:=raw"]
        node = launch_node(
            mem, domain, log, *ros_args, *(["-p", f"keyframes:={keyframes}"] if keyframes else [])
        )
        client = Client(domain, "bench_client")
        diag = client.collect(DiagnosticArray, "/diagnostics")
        # a plain subscriber beside the node, with the node's QoS: what any subscriber got
        plain = client.count(
            Image,
            "/camera/image_raw",
            QoSProfile(depth=NodeSettings().image_depth, reliability=ReliabilityPolicy.RELIABLE),
        )
        lat: dict[str, list[float]] = {"search": [], "ask": []}
        done = threading.Event()
        caller = threading.Thread(target=ros_calls, args=(client, done, lat), daemon=True)
        caller.start()
        t0 = time.monotonic()
        publisher = [sys.executable, str(REPO / "tests/ros/ros_pub.py"), "--data", str(data)]
        pub = subprocess.run(
            [*publisher, "--frames", str(frames), "--rate", str(rate), "--mode", "raw"],
            env=graph_env(domain),
            capture_output=True,
            text=True,
            check=True,
        )
        streamed = time.monotonic() - t0
        done.set()
        caller.join(60)
        sent = json.loads(pub.stdout.strip().splitlines()[-1])

        def counts() -> dict[str, str]:
            return {kv.key: kv.value for kv in diag[-1].status[0].values} if diag else {}

        wait_for(
            lambda: counts().get("waiting for a pose") == "0" and counts().get("queue depth") == "0",
            600,
            "the writer to drain",
        )
        drained = time.monotonic() - t0
        c = {k: v for k, v in counts().items() if not k.startswith("last frame age")}
        client.close()
        text = stop(node, log)
    received, lost, stored = int(c["received"]), int(c["lost in transport"]), int(c["stored"])
    return {
        "frames_offered": sent["images"],
        "seconds_streamed": round(streamed, 1),
        "plain_subscriber_received": plain[0],
        "received": received,
        "lost_in_transport": lost,
        "lost_reported_by_dds": int(c["lost (reported by DDS)"]),
        "every_offered_frame_received_or_counted_lost": received + lost == sent["images"],
        "stored": stored,
        "skipped": {k.removeprefix("skipped: "): int(v) for k, v in c.items() if k.startswith("skipped: ")},
        "every_received_frame_stored_or_skipped": stored + int(c["skipped"]) == received,
        "keyframes_per_s": round(stored / drained, 2),
        "seconds_until_stored": round(drained, 1),
        "search_s": latency(lat["search"]),
        "ask_s": latency(lat["ask"]),
        "node_exit": node.returncode,
        "traceback": "Traceback" in text,
    }


if __name__ == "__main__":
    signal.signal(signal.SIGINT, signal.default_int_handler)
    main()
