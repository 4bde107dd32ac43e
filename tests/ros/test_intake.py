"""The node's intake without rclpy (duck-typed messages, a real LiveWriter over a memory): the
bounded pose buffers, every image accounted for, bad messages counted and never stored."""

from __future__ import annotations

import array
import math
import time
from pathlib import Path
from types import SimpleNamespace as NS

import numpy as np
import pytest

import ravenmem
from ravenmem.ingest.keyframes import KeyframeConfig
from ravenmem.ros import msgs
from ravenmem.ros.intake import BAD_POSE, SKIP_NO_POSE, SKIP_QUEUE, FrameIntake, SequenceGaps
from ravenmem.ros.params import NodeSettings
from ravenmem.ros.tf import GAP, TOO_NEW, TOO_OLD, PoseBuffer, TfBuffer
from ravenmem.runtime.live import LiveWriter
from tests.conftest import ColorEmbedder


def _yaw_q(yaw: float) -> tuple[float, float, float, float]:
    return (0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))


def test_pose_buffer_interpolates_and_stays_bounded() -> None:
    buf = PoseBuffer(history=2.0, size=1000, max_gap=0.5)
    assert buf.at(0.0) == "no pose yet"
    for i in range(1000):  # 10 s at 100 Hz, 2 s kept
        t = i * 0.01
        buf.add(t, (t, 0.0, 0.0), _yaw_q(t))
    assert len(buf) <= 300  # the history window (plus a chunk not yet cut), not 1000
    xyz, q = buf.at(9.005)  # type: ignore[misc]
    assert xyz[0] == pytest.approx(9.005)
    assert math.remainder(2 * math.atan2(q[2], q[3]) - 9.005, 2 * math.pi) == pytest.approx(0.0, abs=1e-9)
    assert buf.at(10.5) == TOO_NEW and buf.at(1.0) == TOO_OLD
    buf.add(9.5, (0.0, 0.0, 0.0), _yaw_q(0))  # a late sample goes in its place
    buf.add(11.0, (0.0, 0.0, 0.0), _yaw_q(0))
    assert buf.at(10.5) == GAP  # 9.99 -> 11.0 is longer than max_gap


def test_tf_buffer_composes_a_chain_and_refuses_a_second_parent() -> None:
    tf = TfBuffer(history=10.0)
    assert tf.add("map", "odom", 0.0, (1.0, 0.0, 0.0), _yaw_q(math.pi / 2), static=True)
    for t in (0.0, 1.0):
        tf.add("odom", "base_link", t, (t, 0.0, 0.0), _yaw_q(0.0), static=False)
    xyz, _ = tf.lookup("map", "base_link", 0.5)  # type: ignore[misc]
    assert xyz == pytest.approx((1.0, 0.5, 0.0))  # odom is turned 90 degrees in map
    assert tf.newest("map", "base_link") == 1.0
    assert not tf.add("world", "odom", 0.0, (0, 0, 0), _yaw_q(0), static=True)  # a second parent
    assert "no transform" in str(tf.lookup("map", "camera", 0.5))


def _image(t: float, value: int = 0, encoding: str = "rgb8", h: int = 8, w: int = 8) -> NS:
    data = array.array("B", bytes([value]) * (h * w * 3))  # as rclpy hands uint8[] over
    return NS(
        header=NS(stamp=NS(sec=int(t), nanosec=int(round((t - int(t)) * 1e9)))),
        height=h,
        width=w,
        encoding=encoding,
        step=w * 3,
        is_bigendian=0,
        data=data,
    )


def _odom(t: float, x: float, qw: float = 1.0) -> NS:
    pose = NS(position=NS(x=x, y=0.0, z=0.0), orientation=NS(x=0.0, y=0.0, z=0.0, w=qw))
    return NS(
        header=NS(stamp=NS(sec=int(t), nanosec=int(round((t - int(t)) * 1e9))), frame_id="odom"),
        pose=NS(pose=pose),
    )


def test_every_image_is_accounted_for_and_bad_messages_are_never_stored(tmp_path: Path) -> None:
    mem = ravenmem.create(tmp_path / "m.mem", embedder=ColorEmbedder(), ocr=False)
    writer = LiveWriter(mem, KeyframeConfig.from_spec("all")).start()
    mem.acquire_writer(wait=False)
    s = NodeSettings(queue_size=3, pose_wait=0.05)
    intake = FrameIntake(writer, s)
    t0 = 1_700_000_000.0
    try:
        intake.odometry(_odom(t0, 0.0), t0)
        for i in range(1, 6):
            intake.image(_image(t0 + i * 0.1 - 0.05, value=i * 40), msgs.IMAGE, t0)
            intake.odometry(_odom(t0 + i * 0.1, i * 0.1), t0)
        intake.image(_image(t0, encoding="yuv_weird"), msgs.IMAGE, t0)
        intake.image(_image(t0, h=0, w=0), msgs.IMAGE, t0)
        intake.odometry(_odom(t0 + 1, float("nan")), t0)
        intake.odometry(_odom(t0 + 1, 1.0, qw=0.0), t0)
        for i in range(5):  # newer than every pose: they wait, the queue holds 3
            intake.image(_image(t0 + 5 + i, value=7), msgs.IMAGE, t0)
        assert len(intake.waiting) == 3
        time.sleep(0.1)
        intake.settle()  # waited past pose_wait: no pose in time
        writer.close()
    finally:
        mem.close()
    c = intake.counts.as_dict(len(intake.waiting))
    assert c["received"] == 12 and intake.counts.balance(len(intake.waiting)) == 0
    assert c["stored"] == 5
    assert c["skipped"][SKIP_QUEUE] == 2 and c["skipped"][SKIP_NO_POSE] == 3
    assert c["bad_messages"][BAD_POSE] == 2
    assert c["bad_messages"]["unsupported encoding 'yuv_weird'"] == 1
    with ravenmem.open(tmp_path / "m.mem", embedder=ColorEmbedder()) as m:
        assert m.count() == 5
        xs = sorted(r.pose.x for r in m.all_records())
    assert xs == pytest.approx([0.05, 0.15, 0.25, 0.35, 0.45])  # interpolated at each stamp
    assert np.isfinite(xs).all()


def test_sequence_gaps_count_the_images_that_never_arrived_per_publisher() -> None:
    gaps = SequenceGaps()
    assert gaps.missed("a", 7) == 0  # the first seen: what came before was not ours to get
    assert gaps.missed("a", 8) == 0 and gaps.missed("a", 12) == 3  # 9, 10, 11 never arrived
    assert gaps.missed("b", 1) == 0 and gaps.missed("b", 3) == 1  # per publisher
    assert gaps.missed("a", 11) == 0 and gaps.missed("a", 13) == 0  # late or repeated: no gap
    assert gaps.missed("a", None) == 0 and gaps.missed(None, 40) == 0  # no number: nothing known
    assert gaps.missed("a", 14) == 0
    for i in range(SequenceGaps.MAX_PUBLISHERS + 5):  # bounded
        gaps.missed(f"p{i}", 1)
    assert len(gaps.last) == SequenceGaps.MAX_PUBLISHERS


def test_the_intake_counts_a_sequence_gap_as_lost_not_received() -> None:
    class Writer:
        def submit(self, *a: object, **k: object) -> object:
            raise AssertionError("no pose: nothing is submitted")

    intake = FrameIntake(Writer(), NodeSettings(pose_wait=60.0))  # type: ignore[arg-type]
    for seq in (1, 2, 5, 6, 9):
        intake.image(_image(1.0, value=seq), msgs.IMAGE, 1.0, "ros", "gid-1", seq)
    c = intake.counts.as_dict(len(intake.waiting))
    assert (c["received"], c["lost_in_transport"], c["lost_reported_by_dds"]) == (5, 4, 0)
    intake.counts.missed(2, reported=True)  # what the middleware reports is kept apart
    assert intake.counts.as_dict()["lost_reported_by_dds"] == 2
