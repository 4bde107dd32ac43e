"""The robot link over real Zenoh: a peer on loopback publishes CDR messages, the link stores them.

Both sessions get explicit tcp/127.0.0.1 endpoints and scouting off, so nothing depends on
multicast. The publisher plays a ROS 2 robot behind zenoh-bridge-ros2dds: topic names as keys,
CDR bytes as payloads.
"""

from __future__ import annotations

import json
import socket
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pytest

import ravenmem
from ravenmem.agent.ask import AskResult
from ravenmem.agent.schema import Answer
from ravenmem.ingest.keyframes import KeyframeConfig, Keyframer
from ravenmem.nav.base import PlanResult
from ravenmem.nav.goals import GoalPlan
from ravenmem.ros import msgs as rosmsg
from ravenmem.ros.link import SKIP_NO_POSE, LinkConfig
from ravenmem.ros.zenoh import ZenohEndpoints, ZenohLink
from ravenmem.types import Frame, Pose
from tests.conftest import ColorEmbedder
from tests.ros import ros_wire as w

zenoh: Any = pytest.importorskip("zenoh", reason="the robot extra (eclipse-zenoh) is not installed")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def peer(endpoint: str, listen: bool = False) -> Any:
    """The robot side: a Zenoh peer that connects to (or listens on) the endpoint, scouting off."""
    conf = zenoh.Config()
    conf.insert_json5("mode", '"peer"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "false")
    conf.insert_json5("listen/endpoints", json.dumps([endpoint] if listen else []))
    conf.insert_json5("connect/endpoints", "[]" if listen else json.dumps([endpoint]))
    conf.insert_json5("timestamping/enabled", "true")  # advanced (caching) publishers need it
    return zenoh.open(conf)


class MemorySink:
    """frame + pose + time -> keyframe rule -> memory, as a live writer does (one thread)."""

    def __init__(self, mem: ravenmem.Memory, cfg: KeyframeConfig) -> None:
        self.mem, self.kf = mem, Keyframer(cfg)

    def __call__(self, image: np.ndarray, pose: Pose, t: float) -> int | str:
        frame = Frame(image=image, t=t, pose=pose, source="zenoh")
        reason = self.kf.pre(frame)
        if reason is not None:
            return reason
        return self.mem.add_frames([frame])[0]


def wait_until(cond: Any, timeout: float = 10.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.02)
    return bool(cond())


@pytest.fixture
def mem(tmp_path: Path) -> Iterator[ravenmem.Memory]:
    with ravenmem.create(tmp_path / "robot.mem", embedder=ColorEmbedder(), ocr=False, thumb_size=64) as m:
        yield m


def test_frames_published_over_zenoh_become_memories(mem: ravenmem.Memory) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    cfg = LinkConfig.from_spec("image=camera/color/image_raw,pose=odom,goal=goal_pose,wait=0.3")
    link = ZenohLink(
        cfg, MemorySink(mem, KeyframeConfig(min_translation=0.15)), ZenohEndpoints(listen=(endpoint,))
    )
    link.start()
    robot = peer(endpoint)
    goals: list[bytes] = []
    try:
        robot.declare_subscriber("goal_pose", lambda s: goals.append(s.payload.to_bytes()))
        pub_img = robot.declare_publisher("camera/color/image_raw")
        pub_odom = robot.declare_publisher("odom")
        assert wait_until(lambda: pub_img.matching_status and pub_odom.matching_status)
        # odometry at 20 Hz from 9.95 s; images at 10 Hz, raw rgb8 / bgr8 and JPEG by turns
        for k in range(17):
            pub_odom.put(w.odom(9.95 + 0.05 * k))
        times = [10.0 + 0.1 * i for i in range(8)]
        for i, t in enumerate(times):  # at 50 frames/s, as a camera sends them
            pic = w.picture(i)
            pub_img.put(w.jpeg(t, pic) if i % 3 == 2 else w.image(t, pic, "bgr8" if i % 3 else "rgb8"))
            time.sleep(0.02)
        pub_img.put(w.image(10.9, w.picture(9)))  # after the last pose: no pose ever comes
        assert wait_until(
            lambda: link.stats.images == 9 and link.link.waiting == 0 and link.link.stats.stored > 0
        )
        # every 2nd frame moved 0.2 m >= 0.15 m from the last kept; the others 0.1 m: too little motion
        stats = link.stats.as_dict()
        assert stats["stored"] == 4, stats
        assert stats["skipped"] == {"too little motion": 4, SKIP_NO_POSE: 1}
        recs = mem.all_records()
        assert [round(r.t, 3) for r in recs] == [10.0, 10.2, 10.4, 10.6]
        for r in recs:
            x, y, yaw = w.motion(r.t)
            assert (r.pose.x, r.pose.y, r.pose.yaw) == pytest.approx((x, y, yaw), abs=1e-9)
            assert r.source == "zenoh"
            img = mem.load_image(r)
            assert img is not None
            pic = w.picture(round((r.t - 10.0) / 0.1))
            assert np.abs(img.astype(int) - pic).mean() < 12  # the thumbnail is the published picture
        # an answer with a plan goes back to the robot as the plan's PoseStamped (here: odom)
        plan = GoalPlan(
            PlanResult(ok=True), goal=(recs[2].pose.x, recs[2].pose.y, recs[2].pose.yaw), frame_id="odom"
        )
        answer = Answer(found=True, position=[0.0, 0.0, 0.0])
        assert link.publish_goal(AskResult(answer, plan=plan))
        assert not link.publish_goal(AskResult(Answer(found=False)))
        assert not link.publish_goal(
            AskResult(Answer(found=True, position=[1.0, 2.0, 0.0]))
        )  # no plan, no planner
        assert wait_until(lambda: len(goals) == 1)
        goal = rosmsg.deserialize(goals[0], rosmsg.POSE_STAMPED)
        assert goal.header.frame_id == "odom"
        assert (goal.pose.position.x, goal.pose.position.y) == pytest.approx((recs[2].pose.x, recs[2].pose.y))
        q = goal.pose.orientation
        assert Pose.from_quaternion(0, 0, 0, q.x, q.y, q.z, q.w).yaw == pytest.approx(recs[2].pose.yaw)
        assert link.stats.goals == 1
    finally:
        robot.close()
        link.close()


def test_tf_over_zenoh_with_tf_static_sent_before_the_link_started(mem: ravenmem.Memory) -> None:
    """/tf_static is sent once when the robot starts; a transient-local publisher (here Zenoh's
    advanced publisher with a cache, as rmw_zenoh uses) keeps it for subscribers that join later."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    robot = peer(endpoint, listen=True)
    static = zenoh.ext.declare_advanced_publisher(
        robot, "tf_static", cache=zenoh.ext.CacheConfig(max_samples=1), publisher_detection=True
    )
    static.put(w.tf_static())  # before anyone listens
    cfg = LinkConfig.from_spec("image=camera/image_raw/compressed,pose=tf")  # parent: map, found in tf
    link = ZenohLink(cfg, MemorySink(mem, KeyframeConfig.only()), ZenohEndpoints(connect=(endpoint,))).start()
    try:
        pubs = {k: robot.declare_publisher(k) for k in ("camera/image_raw/compressed", "tf")}
        assert wait_until(lambda: all(p.matching_status for p in pubs.values()))
        assert wait_until(lambda: link.stats.poses == 1)  # the static transform, from the cache
        for k in range(6):
            pubs["tf"].put(w.tf(9.95 + 0.1 * k))
        for i in range(3):
            pubs["camera/image_raw/compressed"].put(w.jpeg(10.0 + 0.1 * i, w.picture(i)))
        assert wait_until(lambda: link.stats.stored == 3), link.stats
        for r in mem.all_records():
            x, y, yaw = w.in_map(r.t)
            assert (r.pose.x, r.pose.y) == pytest.approx((x, y), abs=1e-9)
            assert r.pose.yaw == pytest.approx(yaw - 2 * np.pi if yaw > np.pi else yaw, abs=1e-9)
    finally:
        link.close()
        robot.close()
