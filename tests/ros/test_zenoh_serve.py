"""`ravenmem serve --zenoh`: a robot on Zenoh (a peer on loopback publishing real CDR messages)
streams into the running service, and the service's answers come back to it as goal poses."""

from __future__ import annotations

import math
import signal
import time
from pathlib import Path
from typing import Any

import httpx
import pytest

import ravenmem
from ravenmem.ros import msgs as rosmsg
from tests.agent.conftest import SCENE
from tests.agent.test_ask_navigate import with_map
from tests.cli.helpers import assert_one_line_error
from tests.ros import ros_wire as w
from tests.ros.test_zenoh_loopback import free_port, peer, wait_until
from tests.server.conftest import make_memory, serve_refused, serve_subprocess

zenoh: Any = pytest.importorskip("zenoh", reason="the robot extra (eclipse-zenoh) is not installed")


def link_info(url: str) -> dict[str, Any]:
    links = httpx.get(url + "/info", timeout=10).json()["links"]
    assert len(links) == 1 and links[0]["kind"] == "zenoh"
    return dict(links[0])


def test_serve_zenoh_stores_frames_and_sends_goals(tmp_path: Path) -> None:
    mem_path = tmp_path / "scene.mem"
    make_memory(mem_path).close()
    with_map(mem_path)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    robot = peer(endpoint, listen=True)  # the robot listens; the service connects to it
    goals: list[bytes] = []
    robot.declare_subscriber("goal_pose", lambda s: goals.append(s.payload.to_bytes()))
    proc, url = serve_subprocess(
        mem_path,
        "--keyframes",
        "min_translation=0.15",
        "--zenoh",
        "image=/camera/color/image_raw,pose=/odom,goal=/goal_pose,wait=0.3",
        "--zenoh-connect",
        endpoint,
    )
    try:
        pub_img = robot.declare_publisher("camera/color/image_raw")
        pub_odom = robot.declare_publisher("odom")
        assert wait_until(lambda: pub_img.matching_status and pub_odom.matching_status, 30)
        info = link_info(url)
        assert (info["image"], info["pose"], info["goal"]) == ("camera/color/image_raw", "odom", "goal_pose")
        for k in range(17):
            pub_odom.put(w.odom(9.95 + 0.05 * k))
        for i in range(8):  # 10.0 .. 10.7 s at 0.1 m a frame: every 2nd moved enough to be kept
            pic = w.picture(i)
            pub_img.put(w.jpeg(10.0 + 0.1 * i, pic) if i % 2 else w.image(10.0 + 0.1 * i, pic, "bgr8"))
            time.sleep(0.05)
        assert wait_until(lambda: (i := link_info(url))["images"] == 8 and i["waiting"] == 0, 60)
        info = link_info(url)
        assert info["stored"] == 4 and info["skipped"] == {"too little motion": 4}, info
        live = httpx.get(url + "/info", timeout=10).json()["live"]
        assert live["kept"] == 4 and live["frames_seen"] == 8
        new = [httpx.get(f"{url}/memories/{info['last_id'] - k}", timeout=10).json() for k in (3, 2, 1, 0)]
        assert [round(m["t"], 3) for m in new] == [10.0, 10.2, 10.4, 10.6]
        for m in new:
            x, y, yaw = w.motion(m["t"])
            assert (m["x"], m["y"], m["yaw"]) == pytest.approx((x, y, yaw), abs=1e-6)
            assert m["source"] == "zenoh"
        # a question answered by the service: its plan's goal goes to the robot (nav.goals.goal_for)
        r = httpx.post(
            url + "/ask", json={"question": "where is the yellow thing?", "method": "offline"}, timeout=60
        )
        answer = r.json()
        assert r.status_code == 200 and answer["position"] is not None, answer
        assert wait_until(lambda: len(goals) == 1, 10)
        goal = rosmsg.deserialize(goals[0], rosmsg.POSE_STAMPED)
        # the memory had no frame yet: it took the odometry's (odom), and its goals are in it
        assert goal.header.frame_id == "odom" and goal.header.stamp.sec > 0  # stamped when sent
        assert httpx.get(url + "/info", timeout=10).json()["frame_id"] == "odom"
        p = goal.pose.position
        assert math.dist((p.x, p.y), answer["position"][:2]) < 0.1 and p.z == 0.0
        assert "frame_id" in link_info(url) and link_info(url)["frame_id"] == "odom"  # the poses' frame
        assert link_info(url)["goals"] == 1
    finally:
        proc.send_signal(signal.SIGINT)
        proc.wait(60)
        robot.close()
    # every frame the link stored is in the memory after the service stopped
    with ravenmem.open(mem_path) as mem:
        live = [r for r in mem.all_records() if r.source == "zenoh"]
        assert mem.count() == len(SCENE) + 4
        assert [round(r.t, 3) for r in live] == [10.0, 10.2, 10.4, 10.6]


def test_serve_zenoh_bad_options(tmp_path: Path) -> None:
    mem_path = tmp_path / "scene.mem"
    make_memory(mem_path).close()
    cases = [
        (["--zenoh", "image=cam"], "pose=KEY is missing"),
        (["--zenoh", "image=cam,pose=odom", "--read-only"], "cannot run with --read-only"),
        (["--zenoh-connect", "tcp/127.0.0.1:7447"], "need --zenoh"),
        (["--zenoh", "image=cam,pose=odom", "--zenoh-connect", "udp:nowhere"], "zenoh endpoints"),
    ]
    for extra, message in cases:  # the real command, the colour embedder registered (serve_color.py)
        r = serve_refused(mem_path, *extra)
        assert message in assert_one_line_error(r), (extra, r.stderr)
    with ravenmem.open(mem_path) as mem:  # nothing was added or broken
        assert mem.count() == len(SCENE)
