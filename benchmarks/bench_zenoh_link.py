"""Throughput of the robot link (not a test; prints numbers).

Run: python benchmarks/bench_zenoh_link.py [--frames 300] [--tf]
Measures, for 640x480 camera frames with odometry at 50 Hz and a sink that only counts (the
embedder and the store are measured elsewhere):
1. the link's own work per frame (CDR decode, pose pairing, image conversion), raw rgb8 and JPEG;
2. the same over Zenoh on loopback (a publishing peer and the link in one process, tcp/127.0.0.1),
   frames published at a camera's rate (30 and 100 frames/s): how many reach the sink, how many
   the link dropped because its queue was full, and the delay from publishing to the sink;
3. (`--tf` alone) the link's cost per /tf message, before and after its TF path moved to the
   node's bounded `TfBuffer`, on one stream: 100 Hz odom -> base_link under a static map -> odom,
   30 s of history, an image waiting (so each message asks for the newest pose, as a camera
   slightly ahead of odometry makes it). Before: `TfTree`, pruned to the history and its whole
   pose track rebuilt per message (the link's code until then, kept here to measure it).
4. (`--odom` alone) the same for a pose topic: 100 Hz odometry, 30 s of history, an image
   waiting, each message added and the pose at a stamp just before it looked up. Before: the
   whole history rebuilt into a `PoseTrack` for the lookup (the link's code until then, kept
   here); after: `PoseHistory`, which matches on the few samples around the stamp.
A camera at 30 fps needs 30 frames/s; ROS image topics are usually 15 to 30 Hz.
"""

from __future__ import annotations

import argparse
import bisect
import io
import json
import math
import socket
import statistics
import time
from typing import Any

import numpy as np
from PIL import Image

from ravenmem.ingest.poses import PoseTrack
from ravenmem.ros import msgs as rosmsg
from ravenmem.ros.link import LinkConfig, PoseHistory, RosLink
from ravenmem.ros.tf import TfTree
from ravenmem.ros.zenoh import ZenohEndpoints, ZenohLink
from ravenmem.types import Pose

H, W = 480, 640
TS = rosmsg.typestore()
T = TS.types


def header(t: float, frame: str) -> Any:
    sec = math.floor(t)
    return T["std_msgs/msg/Header"](
        stamp=T["builtin_interfaces/msg/Time"](sec=sec, nanosec=int((t - sec) * 1e9)), frame_id=frame
    )


def odom(t: float) -> bytes:
    q = T["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=math.sin(t / 20), w=math.cos(t / 20))
    pose = T["geometry_msgs/msg/Pose"](
        position=T["geometry_msgs/msg/Point"](x=t, y=0.0, z=0.0), orientation=q
    )
    cov = T["geometry_msgs/msg/PoseWithCovariance"](pose=pose, covariance=np.zeros(36))
    v = T["geometry_msgs/msg/Vector3"](x=0.0, y=0.0, z=0.0)
    tw = T["geometry_msgs/msg/TwistWithCovariance"](
        twist=T["geometry_msgs/msg/Twist"](linear=v, angular=v), covariance=np.zeros(36)
    )
    msg = T[rosmsg.ODOMETRY](header=header(t, "odom"), child_frame_id="base_link", pose=cov, twist=tw)
    return rosmsg.serialize(msg, rosmsg.ODOMETRY)


def frames(n: int, jpeg: bool) -> list[bytes]:
    rng = np.random.default_rng(0)
    base = rng.integers(0, 255, (H, W, 3), dtype=np.uint8)
    out = []
    for i in range(n):
        t = 1.0 + i / 30
        img = np.roll(base, i, axis=1)
        if jpeg:
            buf = io.BytesIO()
            Image.fromarray(img).save(buf, format="JPEG", quality=80)
            msg = T[rosmsg.COMPRESSED](
                header=header(t, "cam"), format="jpeg", data=np.frombuffer(buf.getvalue(), np.uint8)
            )
            out.append(rosmsg.serialize(msg, rosmsg.COMPRESSED))
        else:
            msg = T[rosmsg.IMAGE](
                header=header(t, "cam"),
                height=H,
                width=W,
                encoding="rgb8",
                is_bigendian=0,
                step=W * 3,
                data=img.reshape(-1),
            )
            out.append(rosmsg.serialize(msg, rosmsg.IMAGE))
    return out


class Count:
    """Counts frames and notes when each arrived (stamp -> perf_counter)."""

    def __init__(self) -> None:
        self.n = 0
        self.arrived: dict[float, float] = {}

    def __call__(self, image: np.ndarray, pose: Pose, t: float) -> int:
        self.n += 1
        self.arrived[round(t, 6)] = time.perf_counter()
        return self.n


def in_process(msgs: list[bytes], poses: list[bytes], label: str) -> None:
    sink = Count()
    link = RosLink(LinkConfig.from_spec("image=cam,pose=odom"), sink)
    for p in poses:
        link.pose("odom", p)
    t0 = time.perf_counter()
    for m in msgs:
        link.image("cam", m)
    dt = time.perf_counter() - t0
    assert sink.n == len(msgs), link.stats
    print(f"link only, {label}: {1000 * dt / len(msgs):.2f} ms/frame = {len(msgs) / dt:.0f} frames/s")


def over_zenoh(msgs: list[bytes], poses: list[bytes], label: str, rate: float) -> None:
    import zenoh

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        endpoint = f"tcp/127.0.0.1:{s.getsockname()[1]}"
    sink = Count()
    link = ZenohLink(
        LinkConfig.from_spec("image=cam,pose=odom"), sink, ZenohEndpoints(listen=(endpoint,))
    ).start()
    conf = zenoh.Config()
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    robot = zenoh.open(conf)
    sent: dict[float, float] = {}
    try:
        pub_img = robot.declare_publisher("cam", congestion_control=zenoh.CongestionControl.BLOCK)
        pub_pose = robot.declare_publisher("odom", congestion_control=zenoh.CongestionControl.BLOCK)
        while not (pub_img.matching_status and pub_pose.matching_status):
            time.sleep(0.01)
        for p in poses:
            pub_pose.put(p)
        t0 = time.perf_counter()
        for i, m in enumerate(msgs):
            while time.perf_counter() < t0 + i / rate:
                time.sleep(0.0005)
            sent[round(1.0 + i / 30, 6)] = time.perf_counter()
            pub_img.put(m)
        deadline = time.perf_counter() + 10
        while sink.n + sum(link.stats.skipped.values()) < len(msgs) and time.perf_counter() < deadline:
            time.sleep(0.005)
    finally:
        robot.close()
        link.close()
    st = link.stats.as_dict()
    delay = sorted(1000 * (sink.arrived[k] - sent[k]) for k in sink.arrived if k in sent)
    p50 = delay[len(delay) // 2] if delay else float("nan")
    p99 = delay[min(len(delay) - 1, int(0.99 * len(delay)))] if delay else float("nan")
    print(
        f"over Zenoh at {rate:.0f} frames/s, {label}: {len(msgs)} published, {sink.n} reached the sink, "
        f"dropped {st['skipped'] or 0}; publish -> sink {p50:.1f} ms p50, {p99:.1f} ms p99"
    )


# ----------------------------------------------------------------------------- /tf, before and after


def tf_message(parts: list[tuple[float, str, str, float]]) -> bytes:
    """A TFMessage of (stamp, parent, child, x) transforms, turning with x."""
    transforms = [
        T["geometry_msgs/msg/TransformStamped"](
            header=header(t, parent),
            child_frame_id=child,
            transform=T["geometry_msgs/msg/Transform"](
                translation=T["geometry_msgs/msg/Vector3"](x=x, y=0.0, z=0.0),
                rotation=T["geometry_msgs/msg/Quaternion"](
                    x=0.0, y=0.0, z=math.sin(x / 2), w=math.cos(x / 2)
                ),
            ),
        )
        for t, parent, child, x in parts
    ]
    return rosmsg.serialize(T[rosmsg.TF](transforms=transforms), rosmsg.TF)


class TreePath:
    """The link's TF path before `TfBuffer`: every transform into a `TfTree`, the moving edges
    pruned to the history (the rule `TfTree.prune` had), and the pose track rebuilt to answer
    the newest pose."""

    def __init__(self, history: float) -> None:
        self.tree, self.history = TfTree(), history

    def add(self, samples: list[rosmsg.TfSample], static: bool) -> None:
        for s in samples:
            self.tree.add(s.parent, s.child, s.t, s.xyz, s.quat, static=static)
            if not static:
                self.prune(s.t - self.history)

    def prune(self, before: float) -> None:
        for e in self.tree.edges.values():
            if e.static or not e.t or e.t[0] >= before:
                continue
            order = np.argsort(np.asarray(e.t), kind="stable")
            ts = np.asarray(e.t)[order]
            keep = order[max(int(np.searchsorted(ts, before, side="right")) - 1, 0) :]
            e.t, e.xyz, e.quat = [e.t[i] for i in keep], [e.xyz[i] for i in keep], [e.quat[i] for i in keep]

    @property
    def newest(self) -> float | None:
        return self.tree.track("map", "base_link").span[1]

    def kept(self) -> int:
        return sum(len(e.t) for e in self.tree.edges.values() if not e.static)


def tf_costs(seconds: float = 40.0, history: float = 30.0, rate: float = 100.0) -> None:
    """Per /tf message, on the messages after the history has filled: decoding, the TF path
    before and after (no decoding), and the whole `RosLink.pose` after (decode + path + pairing)."""
    t0 = 1_700_000_000.0
    static = tf_message([(t0, "map", "odom", 1.0)])
    stream = [
        tf_message([(t0 + k / rate, "odom", "base_link", math.sin(k / 100))])
        for k in range(int(seconds * rate))
    ]
    cfg = LinkConfig.from_spec(f"image=cam,pose=tf,history={history:g}")
    before, after = TreePath(history), PoseHistory(cfg)
    link = RosLink(cfg, Count(), monotonic=lambda: 0.0)  # its clock stands still: the image waits
    far = T[rosmsg.IMAGE](  # newer than every pose: it waits, and each message asks for the newest
        header=header(t0 + 1e6, "cam"),
        height=1,
        width=1,
        encoding="rgb8",
        is_bigendian=0,
        step=3,
        data=np.zeros(3, np.uint8),
    )
    for i, payload in enumerate([static, *stream]):
        samples = list(rosmsg.tf_samples(rosmsg.deserialize(payload, rosmsg.TF), 0.0))
        before.add(samples, static=i == 0)
        for s in samples:
            after.add_tf(s, static=i == 0)
        link.pose("tf_static" if i == 0 else "tf", payload)
        if i == int(history * rate):
            break
    link.image("cam", rosmsg.serialize(far, rosmsg.IMAGE))
    assert link.waiting == 1
    cost: dict[str, list[float]] = {"decode": [], "before": [], "after": [], "link": []}
    window = stream[int(history * rate) :]
    for payload in window:  # after (and decoding), then before: one's garbage not in the other's times
        a = time.perf_counter()
        samples = list(rosmsg.tf_samples(rosmsg.deserialize(payload, rosmsg.TF), 0.0))
        b = time.perf_counter()
        for s in samples:
            after.add_tf(s, static=False)
        assert after.newest is not None
        c = time.perf_counter()
        link.pose("tf", payload)
        d = time.perf_counter()
        for k, dt in (("decode", b - a), ("after", c - b), ("link", d - c)):
            cost[k].append(dt * 1e3)
    for payload in window:
        samples = list(rosmsg.tf_samples(rosmsg.deserialize(payload, rosmsg.TF), 0.0))
        a = time.perf_counter()
        before.add(samples, static=False)
        assert before.newest is not None
        cost["before"].append((time.perf_counter() - a) * 1e3)
    assert link.waiting == 1 and after.tf is not None and link.poses.tf is not None
    n = len(cost["after"])

    def line(name: str, ms: list[float]) -> str:
        q = statistics.quantiles(ms, n=100)
        return f"{name}: p50 {statistics.median(ms):.4f} ms, p99 {q[98]:.4f} ms, max {max(ms):.3f} ms"

    print(
        f"/tf at {rate:g} Hz, {history:g} s of history, {n} messages timed after it filled, an image waiting:"
    )
    print("  " + line("CDR decode (both)", cost["decode"]))
    print(
        "  " + line(f"before, TfTree (prune + track rebuild), {before.kept()} samples kept", cost["before"])
    )
    print("  " + line(f"after, TfBuffer (the node's), {len(after.tf)} samples kept", cost["after"]))
    print("  " + line("after, the whole RosLink.pose (decode + TfBuffer + pairing)", cost["link"]))
    print(f"  before/after p50: {statistics.median(cost['before']) / statistics.median(cost['after']):.0f}x")


def odom_costs(seconds: float = 40.0, history: float = 30.0, rate: float = 100.0) -> None:
    """Per odometry message after the history has filled: add it and look up the pose 5 ms
    before it, before (the whole kept history as one `PoseTrack`) and after (`PoseHistory`)."""
    t0 = 1_700_000_000.0
    cfg = LinkConfig.from_spec(f"image=cam,pose=odom,history={history:g}")
    after = PoseHistory(cfg)
    kept: list[rosmsg.Sample] = []
    stream = [
        rosmsg.Sample(t0 + k / rate, (k / rate, math.sin(k / 100), 0.0), (0.0, 0.0, 0.0, 1.0))
        for k in range(int(seconds * rate))
    ]
    filled = int(history * rate)
    for s in stream[:filled]:
        after.add(s, "odom")
        kept.append(s)
    cost: dict[str, list[float]] = {"before": [], "after": []}
    for s in stream[filled:]:
        a = time.perf_counter()
        after.add(s, "odom")
        assert isinstance(after.lookup(s.t - 0.005), Pose)
        b = time.perf_counter()
        kept.append(s)
        cut = (
            bisect.bisect_left([k.t for k in kept[:2]], s.t - history) - 1
        )  # the link's rule, a sample a time
        if cut > 0:
            del kept[:cut]
        track = PoseTrack([k.t for k in kept], [k.xyz for k in kept], [k.quat for k in kept])
        assert isinstance(track.match(s.t - 0.005), Pose)
        c = time.perf_counter()
        cost["after"].append((b - a) * 1e3)
        cost["before"].append((c - b) * 1e3)
    med = {k: statistics.median(v) for k, v in cost.items()}
    print(
        f"odometry at {rate:g} Hz, {history:g} s of history, {len(cost['after'])} messages timed, an image waiting:"
    )
    print(
        f"  before, the whole history as a PoseTrack per lookup ({len(kept)} samples): p50 {med['before']:.4f} ms"
    )
    print(f"  after, PoseHistory (the samples around the stamp): p50 {med['after']:.4f} ms")
    print(f"  before/after p50: {med['before'] / med['after']:.0f}x")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--frames", type=int, default=150)
    ap.add_argument("--tf", action="store_true", help="only the /tf cost, before and after")
    ap.add_argument("--odom", action="store_true", help="only the pose topic's cost, before and after")
    args = ap.parse_args()
    if args.tf:
        tf_costs()
        return
    if args.odom:
        odom_costs()
        return
    n = args.frames
    poses = [odom(0.9 + k / 50) for k in range(int((n / 30 + 0.3) * 50))]
    for jpeg in (False, True):
        label = "JPEG CompressedImage" if jpeg else "rgb8 Image (921 KB)"
        msgs = frames(n, jpeg)
        in_process(msgs, poses, label)
        for rate in (30.0, 100.0):
            over_zenoh(msgs, poses, label, rate)


if __name__ == "__main__":
    main()
