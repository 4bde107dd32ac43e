"""The robot link's TF path is the rclpy node's: the same bounded `TfBuffer`, the same poses for
the same /tf messages, the same refusals in the same words. The node's side is its intake
(`ros.intake.FrameIntake`, which the node's callbacks feed) with a writer that keeps what it is
given; the link's side is `RosLink` fed the CDR bytes."""

from __future__ import annotations

import math
from concurrent.futures import Future
from types import SimpleNamespace as NS
from typing import Any

import numpy as np
import pytest

from ravenmem.ros import msgs as rosmsg
from ravenmem.ros.intake import FrameIntake
from ravenmem.ros.link import SKIP_NO_POSE, LinkConfig, RosLink
from ravenmem.ros.params import NodeSettings
from ravenmem.ros.tf import GAP, REFUSED, TOO_OLD
from ravenmem.types import Pose
from tests.ros import ros_wire as w
from tests.ros.test_link import POSE_TIMES, Recorder, assert_pose, link

RATE = 50.0  # Hz of odom -> base_footprint; map -> odom comes at a fifth of it
GAP_FROM, GAP_TO = 18.4, 19.6  # no odom -> base_footprint in between: longer than the 1 s interpolated


def base_in_odom(t: float) -> tuple[float, float, float]:
    return 0.3 * t, math.sin(0.2 * t), 0.4 * t


def odom_in_map(t: float) -> tuple[float, float, float]:
    return 0.01 * t, -0.02 * t, 0.3 + 0.001 * t


FOOT_TO_BASE = (0.1, 0.0, 0.05)  # /tf_static base_footprint -> base_link: x, y, yaw


def truth(t: float) -> tuple[float, float, float]:
    """base_link in map, composed from the three transforms above."""
    x, y, yaw = 0.0, 0.0, 0.0
    for dx, dy, dyaw in (odom_in_map(t), base_in_odom(t), FOOT_TO_BASE):
        x, y = x + math.cos(yaw) * dx - math.sin(yaw) * dy, y + math.sin(yaw) * dx + math.cos(yaw) * dy
        yaw += dyaw
    return x, y, yaw


def tf_message(*parts: tuple[float, str, str, tuple[float, float, float]]) -> bytes:
    """One TFMessage holding each (stamp, parent, child, (x, y, yaw))."""
    transforms = [w.MSGS.tf(t, p, c, *xyyaw).transforms[0] for t, p, c, xyyaw in parts]
    return w.cdr(w.MSGS.T("tf2_msgs/msg/TFMessage")(transforms=transforms))


def stream(seconds: float = 20.0) -> list[tuple[str, bytes]]:
    """(key, CDR) in arrival order: /tf_static once, then odom -> base_footprint at RATE with
    jittered stamps (one pair arriving out of order, a 1.2 s gap near the end) and map -> odom at
    RATE / 5 in the same messages."""
    rng = np.random.default_rng(7)
    out = [("tf_static", tf_message((0.0, "base_footprint", "base_link", FOOT_TO_BASE)))]
    for k in range(1, int(seconds * RATE) + 1):  # from a non-zero stamp (zero: the receive time)
        t = k / RATE + float(rng.uniform(-0.003, 0.003))
        parts = [] if GAP_FROM < t < GAP_TO else [(t, "odom", "base_footprint", base_in_odom(t))]
        if k % 5 == 0:
            parts.append((k / RATE, "map", "odom", odom_in_map(k / RATE)))
        if parts:
            out.append(("tf", tf_message(*parts)))
    out[100], out[101] = out[101], out[100]  # a late message goes in its place
    return out


class NodeWriter:
    """The node's writer as its intake sees it (`LiveWriter.submit`): keeps every posed frame."""

    def __init__(self) -> None:
        self.frames: list[tuple[Pose, float]] = []

    def submit(self, image: np.ndarray, pose: Pose, t: float, source: str) -> Future[Any]:
        self.frames.append((pose, t))
        fut: Future[Any] = Future()
        fut.set_result(NS(id=len(self.frames) - 1, skipped=None))
        return fut


def test_the_link_and_the_node_pose_the_same_tf_stream_alike_in_bounded_memory() -> None:
    messages = stream()
    image_times = [0.5, 18.05, 18.111, 18.2, 18.37, 19.0, 19.7, 19.93, 25.0]
    sink = Recorder()
    lk = RosLink(LinkConfig.from_spec("image=cam,pose=tf,history=2"), sink, clock=lambda: 5000.0)
    writer = NodeWriter()
    intake = FrameIntake(writer, NodeSettings(odom_topic="", history=2.0, pose_wait=60.0))  # type: ignore[arg-type]
    for key, payload in messages:
        lk.pose(key, payload)
        intake.transforms(rosmsg.deserialize(payload, rosmsg.TF), 5000.0, static=key == "tf_static")
    for i, t in enumerate(image_times):
        lk.image("cam", w.image(t, w.picture(i)))
        intake.image(rosmsg.deserialize(w.image(t, w.picture(i)), rosmsg.IMAGE), rosmsg.IMAGE, 5000.0)
    lk.flush()
    intake.settle(flush=True)

    # the same outcomes, in the node's words: too old, across the gap, newer than every pose
    assert lk.stats.skipped == intake.counts.skipped == {TOO_OLD: 1, GAP: 1, SKIP_NO_POSE: 1}
    assert TOO_OLD == "older than the pose history" and GAP == "pose gap too long"
    # the same poses, interpolated at each stamp through the chain map -> odom -> base_footprint -> base_link
    posed = [18.05, 18.111, 18.2, 18.37, 19.7, 19.93]
    assert [t for _, _, t in sink.frames] == [t for _, t in writer.frames] == posed
    for (_, got, t), (want, _) in zip(sink.frames, writer.frames, strict=True):
        assert (got.x, got.y, got.z, got.yaw) == pytest.approx((want.x, want.y, want.z, want.yaw), abs=1e-12)
        assert got.quat == pytest.approx(want.quat, abs=1e-12)
        x, y, yaw = truth(t)
        assert (got.x, got.y) == pytest.approx((x, y), abs=2e-3)  # linear between 20 ms samples
        assert math.remainder(got.yaw - yaw, 2 * math.pi) == pytest.approx(0.0, abs=2e-3)
    assert lk.poses.frame == "map" and lk.poses.parent == "map" and intake.frame is None
    # bounded: 2 s of history at 50 Hz (plus the chunk not cut yet), the same samples as the node
    assert lk.poses.tf is not None and intake.tf is not None
    buf = lk.poses.tf.moving["base_footprint"]
    assert buf.t[0] <= 20.0 - 2.0 and len(buf) <= 2.0 * RATE + 64 + 1 < len(messages) / 4
    assert len(lk.poses.tf) == len(intake.tf) and buf.t == intake.tf.moving["base_footprint"].t


@pytest.mark.parametrize(("max_gap", "posed"), [(0.5, False), (2.0, True)])
def test_the_nodes_tf_path_interpolates_across_gaps_up_to_its_max_gap(max_gap: float, posed: bool) -> None:
    """The node's `max_gap` parameter holds for /tf as for odometry: the stream's 1.2 s gap is
    refused under the default 0.5 s and interpolated across under 2 s."""
    writer = NodeWriter()
    settings = NodeSettings(odom_topic="", history=30.0, pose_wait=60.0, max_gap=max_gap)
    intake = FrameIntake(writer, settings)  # type: ignore[arg-type]
    for key, payload in stream():
        intake.transforms(rosmsg.deserialize(payload, rosmsg.TF), 5000.0, static=key == "tf_static")
    intake.image(rosmsg.deserialize(w.image(19.0, w.picture(0)), rosmsg.IMAGE), rosmsg.IMAGE, 5000.0)
    intake.settle(flush=True)
    assert [t for _, t in writer.frames] == ([19.0] if posed else [])
    assert intake.counts.skipped == ({} if posed else {GAP: 1})


@pytest.mark.parametrize("history", [1.0, 4.0])
def test_a_long_tf_stream_keeps_the_configured_history(history: float) -> None:
    """100 Hz /tf for 40 s: the link keeps `history` seconds of samples (the node's rule), and
    an image older than that is refused, not posed from a forgotten pose."""
    sink = Recorder()
    lk = link(f"image=cam,pose=tf,tf_parent=odom,history={history:g}", sink)
    for k in range(4000):
        lk.pose("tf", w.tf(10.0 + k / 100))
        if k % 100 == 0:  # a /tf_static sent again (a bridge's cache, a restarted publisher)
            lk.pose("tf_static", w.tf_static())
        if k % 500 == 499:
            assert lk.poses.tf is not None
            assert len(lk.poses.tf) <= history * 100 + 64 + 1 and len(lk.poses.tf.static) == 1
    assert lk.poses.tf is not None and len(lk.poses.tf) >= history * 100
    newest = 10.0 + 3999 / 100
    lk.image("cam", w.image(newest - history + 0.005, w.picture(0)))
    lk.image("cam", w.image(20.0, w.picture(1)))
    assert lk.stats.skipped == {TOO_OLD: 1} and lk.stats.stored == 1
    assert_pose(sink.frames[0][1], *w.motion(newest - history + 0.005))
    assert lk.poses.latest_xy() == pytest.approx(w.motion(newest)[:2], abs=1e-9)


def test_nearest_matching_on_tf() -> None:
    sink = Recorder()
    lk = link("image=cam,pose=tf,tf_parent=odom,pose_match=nearest,max_gap=0.02", sink)
    for t in POSE_TIMES:
        lk.pose("tf", w.tf(t))
    lk.image("cam", w.image(10.06, w.picture(0)))  # 10.05 is 0.01 s away
    lk.image("cam", w.image(10.1, w.picture(1)))  # 0.05 s from both
    lk.image("cam", w.image(9.9, w.picture(2)))  # 0.05 s before the first
    assert lk.stats.skipped == {GAP: 1, TOO_OLD: 1} and lk.stats.stored == 1
    assert_pose(sink.frames[0][1], *w.motion(10.05))
    assert sink.frames[0][2] == pytest.approx(10.06)
    lk.image("cam", w.image(10.76, w.picture(3)))  # after the newest: waits for a later pose
    assert lk.waiting == 1
    lk.flush()  # none came: the newest, 0.01 s away, is the nearest
    assert lk.stats.stored == 2 and sink.frames[1][2] == pytest.approx(10.76)
    assert_pose(sink.frames[1][1], *w.motion(POSE_TIMES[-1]))


def test_tf_refusals_and_notes() -> None:
    """A second parent of a frame is refused and counted, as the node does; `tf_note` (shown in
    /info) says why no pose can be found yet."""
    sink = Recorder()
    lk = link("image=cam,pose=tf,tf_parent=map", sink)
    lk.pose("tf", w.tf(10.0))
    lk.pose("tf", w.cdr(w.MSGS.tf(10.0, "world", "base_link", 0.0, 0.0, 0.0)))  # base_link has odom
    assert lk.stats.skipped == {REFUSED: 1}
    lk.image("cam", w.image(10.0, w.picture(0)))
    assert lk.waiting == 1 and lk.poses.tf_note == "no transform from 'map' to 'base_link' in tf yet"
    lk.pose("tf_static", w.tf_static())
    assert lk.waiting == 0 and lk.stats.stored == 1 and lk.poses.tf_note == ""
    assert_pose(sink.frames[0][1], *w.in_map(10.0))
    lk2 = link("image=cam,pose=tf", Recorder())
    lk2.pose("tf_static", w.tf_static())
    assert lk2.poses.latest_xy() is None
    assert lk2.poses.tf_note == "no map/odom/world ancestor of 'base_link' in tf yet"
