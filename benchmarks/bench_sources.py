"""Throughput of the ingest sources (not a test; prints numbers).

Run: python benchmarks/bench_sources.py [--tum ../shared/data/tum_fr1_rpy]
Measures: TUM JPEG source, PyAV video decode (with and without the fps prefilter), ROS 2 MCAP
raw-image source (with peak Python heap, to show it streams), and pose-track lookups.
"""

from __future__ import annotations

import argparse
import tempfile
import time
import tracemalloc
from collections.abc import Iterable
from pathlib import Path

import av
import numpy as np
from rosbags.rosbag2 import StoragePlugin, Writer
from rosbags.typesys import Stores, get_typestore

from ravenmem.ingest.poses import PoseTrack, load_pose_track
from ravenmem.ingest.tum import TumSource
from ravenmem.ingest.video import VideoSource
from ravenmem.ros.bag import RosbagSource

H, W = 480, 640


def _timed(label: str, src: Iterable[object], n_bytes: int | None = None, repeat: int = 1) -> None:
    """Best of `repeat` full iterations (the machine may be shared)."""
    best = float("inf")
    for _ in range(repeat):
        t0 = time.perf_counter()
        n = sum(1 for _ in src)
        best = min(best, time.perf_counter() - t0)
    extra = f", {n_bytes / 1e6:.0f} MB on disk" if n_bytes else ""
    print(f"{label}: {n} frames in {best:.2f} s = {n / best:.0f} frames/s{extra}")


def bench_video(d: Path, n: int = 300) -> None:
    path = d / "bench.mp4"
    rng = np.random.default_rng(0)
    base = rng.integers(0, 255, (H, W + n, 3), dtype=np.uint8)
    with av.open(str(path), "w") as c:
        s = c.add_stream("libx264", rate=30)
        s.width, s.height, s.pix_fmt = W, H, "yuv420p"
        for i in range(n):
            f = av.VideoFrame.from_ndarray(np.ascontiguousarray(base[:, i : i + W]), format="rgb24")
            f.pts = i
            for p in s.encode(f):
                c.mux(p)
        for p in s.encode():
            c.mux(p)
    track = PoseTrack([0.0, n / 30], [[0.0, 0.0, 0.0], [n / 30, 0.0, 0.0]], yaw=[0.0, 1.0])
    _timed(f"video h264 {W}x{H} all frames", VideoSource(path, poses=track), path.stat().st_size, repeat=3)
    _timed(
        f"video h264 {W}x{H} fps=2 prefilter (decodes all, converts 20)",
        VideoSource(path, poses=track, fps=2.0),
        repeat=3,
    )


def bench_bag(d: Path, n: int = 100) -> None:
    ts = get_typestore(Stores.ROS2_HUMBLE)
    path = d / "bench_bag"
    img_t, hdr_t, time_t = (
        ts.types[k] for k in ("sensor_msgs/msg/Image", "std_msgs/msg/Header", "builtin_interfaces/msg/Time")
    )
    data = np.random.default_rng(0).integers(0, 255, H * W * 3, dtype=np.uint8)
    pose_t = ts.types["geometry_msgs/msg/PoseStamped"]
    with Writer(path, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        ci = w.add_connection("/cam", "sensor_msgs/msg/Image", typestore=ts)
        cp = w.add_connection("/pose", "geometry_msgs/msg/PoseStamped", typestore=ts)
        P, Q = ts.types["geometry_msgs/msg/Point"], ts.types["geometry_msgs/msg/Quaternion"]
        for k in range(n * 10 + 1):
            t = k / 100
            hdr = hdr_t(stamp=time_t(sec=int(t), nanosec=int(round((t % 1) * 1e9))), frame_id="map")
            pose = ts.types["geometry_msgs/msg/Pose"](
                position=P(x=t, y=0.0, z=0.0), orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0)
            )
            w.write(cp, int(t * 1e9) + 1, ts.serialize_cdr(pose_t(header=hdr, pose=pose), pose_t.__msgtype__))
            if k % 10 == 5 and k < n * 10:
                msg = img_t(
                    header=hdr, height=H, width=W, encoding="rgb8", is_bigendian=0, step=W * 3, data=data
                )
                w.write(ci, int(t * 1e9), ts.serialize_cdr(msg, img_t.__msgtype__))
    size = sum(f.stat().st_size for f in path.iterdir())
    tracemalloc.start()
    _timed(f"ROS 2 MCAP bag, {n} rgb8 {W}x{H} images", RosbagSource(path), size)
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    print(f"  peak Python heap while reading: {peak / 1e6:.1f} MB (bag {size / 1e6:.0f} MB)")


def bench_pose_file(d: Path, n: int = 360_000) -> None:
    path = d / "big_tum.txt"
    rng = np.random.default_rng(0)
    np.savetxt(path, np.column_stack([np.arange(n) * 0.01, rng.normal(size=(n, 7))]), fmt="%.6f")
    t0 = time.perf_counter()
    load_pose_track(path)
    print(f"load a TUM pose file of {n} rows (1 h at 100 Hz): {time.perf_counter() - t0:.2f} s")


def bench_poses(tum: Path) -> None:
    t0 = time.perf_counter()
    tr = load_pose_track(tum / "groundtruth.txt")
    print(f"load groundtruth.txt ({len(tr)} rows): {(time.perf_counter() - t0) * 1e3:.1f} ms")
    q = np.random.default_rng(0).uniform(tr.t[0], tr.t[-1], 100_000)
    t0 = time.perf_counter()
    tr.interpolate_many(q)
    print(f"interpolate_many 100k times (slerp): {(time.perf_counter() - t0) * 1e3:.1f} ms")
    t0 = time.perf_counter()
    for x in q[:2000]:
        tr.interpolate(float(x))
    print(f"interpolate one at a time: {(time.perf_counter() - t0) / 2000 * 1e6:.0f} us per call")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument(
        "--tum", type=Path, default=Path(__file__).resolve().parents[2].parent / "shared/data/tum_fr1_rpy"
    )
    args = ap.parse_args()
    if (args.tum / "rgb.txt").is_file():
        _timed("TUM fr1_rpy (JPEG 640x480)", TumSource(args.tum))
        bench_poses(args.tum)
    with tempfile.TemporaryDirectory() as d:
        bench_pose_file(Path(d))
        bench_video(Path(d))
        bench_bag(Path(d))


if __name__ == "__main__":
    main()
