"""The node on a real ROS 2 graph: `ravenmem ros run` in its own process, the TUM recording
streamed by another (tests/ros/ros_pub.py), a /map publisher and a NavigateToPose server
(tests/ros/ros_peers.py), and rclpy clients here; Fast DDS limited to this host, one ROS domain
per module. Every frame the node received is accounted for (stored, or skipped with a reason);
goals go out only for a question that asks to navigate; SIGTERM exits 0 with the queue stored."""

from __future__ import annotations

import json
import re
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from PIL import Image as PILImage

import ravenmem
from tests.conftest import TUM, tum_data
from tests.ros.rosgraph import Client, graph_env, launch_node, launch_peer, require_ros, stop, wait_for

pytestmark = pytest.mark.ros
DOMAIN = 117  # this module's ROS domain (other modules of tests/ros use others)
HERE = Path(__file__).parent


@pytest.fixture(scope="module")
def ros() -> Path:
    """The TUM recording, once ROS 2 is known to be here."""
    require_ros()
    return tum_data()


def _node(mem: Path, log: Path, *ros_args: str) -> subprocess.Popen[str]:
    return launch_node(mem, DOMAIN, log, *ros_args)


def _peer(what: str, log: Path, *args: str) -> subprocess.Popen[str]:
    return launch_peer(what, DOMAIN, log, *args)


def _publish(*args: str) -> dict[str, Any]:
    r = subprocess.run(
        [sys.executable, str(HERE / "ros_pub.py"), "--data", str(TUM), *args],
        env=graph_env(DOMAIN),
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert r.returncode == 0, r.stderr[-3000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


def _diag(box: list[Any]) -> dict[str, str]:
    if not box:
        return {}
    return {kv.key: kv.value for kv in box[-1].status[0].values}


def _ask_by_action(action: Any, goal: Any) -> tuple[Any, list[Any]]:
    """Send one question to the question action and wait until it is accepted and answered:
    (the result response, with .status and .result; the feedback messages received)."""
    feedback: list[Any] = []
    accepted = action.send_goal_async(goal, feedback_callback=feedback.append)
    wait_for(lambda: accepted.done(), 60, "the action to accept the goal")
    ended = accepted.result().get_result_async()
    wait_for(lambda: ended.done(), 120, "the action's result")
    return ended.result(), feedback


def _ingest(mem: Path) -> dict[str, Any]:
    manifest = json.loads((mem / "memory.json").read_text())
    return next(r for r in manifest["ingests"] if r.get("source") == "ros")


def test_raw_images_odometry_services_goals_sigterm(ros: Path, tmp_path: Path) -> None:
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseStamped
    from ravenmem_msgs.srv import Ask, Search
    from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image
    from visualization_msgs.msg import MarkerArray

    mem = tmp_path / "robot.mem"
    map_log, node_log = tmp_path / "map.log", tmp_path / "node.log"
    peer = _peer("map", map_log, "--ros-args", "-r", "__ns:=/bot1")
    node = _node(
        mem,
        node_log,
        "-r",
        "__ns:=/bot1",
        "-p",
        "image_qos:=reliable",
        "-p",
        "image_transport:=raw",
        "-p",
        "markers_period:=0.5",
        "-p",
        "diagnostics_period:=0.5",
    )
    client = Client(DOMAIN)
    try:
        goals = client.collect(PoseStamped, "/bot1/goal_pose")
        diag = client.collect(DiagnosticArray, "/diagnostics")
        latched = QoSProfile(
            depth=10, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL
        )
        markers = client.collect(MarkerArray, "/bot1/ravenmem/markers", latched)
        # a best-effort odometry publisher, and bad messages of every kind after the frames
        sent = _publish(
            "--frames",
            "90",
            "--mode",
            "raw",
            "--pose-reliability",
            "best_effort",
            "--bad",
            "--ros-args",
            "-r",
            "__ns:=/bot1",
        )
        wait_for(
            lambda: (
                _diag(diag).get("received") == str(sent["images"])
                and _diag(diag).get("waiting for a pose") == "0"
                and _diag(diag).get("queue depth") == "0"
            ),
            40,
            "the node to settle every frame",
            show=lambda: (sent, _diag(diag), len(diag)),
        )
        d = _diag(diag)
        assert int(d["stored"]) >= 2
        assert int(d["stored"]) + int(d["skipped"]) == sent["images"]
        assert d["bad message: unsupported encoding 'yuv422_weird'"] == "1"
        assert d["bad message: malformed image message"] == "2"  # the 0x0 and the truncated one
        # a NaN position and a zero quaternion, sent best-effort: at least one arrives
        assert int(d["bad message: invalid pose (NaN or zero quaternion)"]) >= 1
        assert d["bad message: camera info without K"] == "1"

        found = client.call(
            Search, "/bot1/ravenmem/search", Search.Request(tool="time", query="2011-05-10", k=3)
        )
        assert found.error == "" and len(found.memories) == 3  # type: ignore[attr-defined]
        assert {m.pose.header.frame_id for m in found.memories} == {"odom"}  # type: ignore[attr-defined]
        bad = client.call(Search, "/bot1/ravenmem/search", Search.Request(tool="text", query="desk", k=5000))
        assert "k must be" in bad.error  # type: ignore[attr-defined]

        plain = client.call(
            Ask, "/bot1/ravenmem/ask", Ask.Request(question="where is the desk?", navigate=False)
        )
        assert plain.found and plain.goal.header.frame_id == ""  # type: ignore[attr-defined]
        # a query picture in the request (sensor_msgs/Image): one of the recording's frames
        with PILImage.open(sorted((TUM / "rgb").iterdir())[40]) as im:
            pic = np.asarray(im.convert("RGB").resize((160, 120)))
        query = Image(height=120, width=160, encoding="rgb8", step=480, data=pic.tobytes())
        seen = client.call(
            Ask, "/bot1/ravenmem/ask", Ask.Request(question="where did I see this?", image=query)
        )
        assert seen.found and seen.reason == "", seen.reason  # type: ignore[attr-defined]
        drive = client.call(
            Ask, "/bot1/ravenmem/ask", Ask.Request(question="where is the desk?", navigate=True)
        )
        assert drive.found and drive.reason == "", drive.reason  # type: ignore[attr-defined]
        assert drive.goal.header.frame_id == "odom" and drive.goal.header.stamp.sec > 0  # type: ignore[attr-defined]
        wait_for(lambda: len(goals) >= 1, 30, "the goal on /bot1/goal_pose")
        # messages of one publisher arrive in order: the navigate=false answer published none
        assert len(goals) == 1
        g = goals[0]
        assert g.header.frame_id == "odom" and g.header.stamp.sec > 1_700_000_000  # type: ignore[attr-defined]
        assert (g.pose.position.x, g.pose.position.y) == pytest.approx(  # type: ignore[attr-defined]
            (drive.goal.pose.position.x, drive.goal.pose.position.y)  # type: ignore[attr-defined]
        )
        wait_for(
            lambda: any(m.ns == "goal" for ma in markers for m in ma.markers), 30, "the answer's markers"
        )
        assert any(m.ns == "memories" and len(m.points) >= 2 for ma in markers for m in ma.markers)  # type: ignore[attr-defined]
    finally:
        client.close()
        text = stop(node, node_log)
        stop(peer, map_log)
    assert node.returncode == 0, text[-3000:]
    assert "Traceback" not in text and "Exception" not in text, text[-3000:]
    run = _ingest(mem)["counts"]
    assert run["received"] == sent["images"]
    assert run["stored"] + sum(run["skipped"].values()) == run["received"]
    assert run["pending"] == 0 and run["in_writer"] == 0 and run["goals"] == 1
    with ravenmem.open(mem) as m:
        assert m.count() == run["stored"]
        assert m.frame_id == "odom"
    assert _ingest(mem)["camera_info"]["k"][0] == pytest.approx(517.3)


def test_compressed_tf_params_file_sim_time_navigate_to_pose(ros: Path, tmp_path: Path) -> None:
    from action_msgs.msg import GoalStatus
    from diagnostic_msgs.msg import DiagnosticArray
    from geometry_msgs.msg import PoseStamped
    from ravenmem_msgs.action import Ask as AskAction
    from ravenmem_msgs.srv import Ask
    from rclpy.action import ActionClient
    from rosgraph_msgs.msg import Clock

    mem = tmp_path / "robot.mem"
    params = tmp_path / "ravenmem.yaml"
    params.write_text(
        "ravenmem:\n  ros__parameters:\n    odom_topic: ''\n    image_qos: reliable\n"
        "    navigate_action: navigate_to_pose\n    use_sim_time: true\n    keyframes: all\n"
        "    image_topics: [camera2/image_raw]\n"
    )
    nav_goals = tmp_path / "nav_goals.jsonl"
    logs = {k: tmp_path / f"{k}.log" for k in ("map", "nav", "node")}
    peers = [_peer("map", logs["map"]), _peer("nav", logs["nav"], "--log", str(nav_goals), "--seconds", "3")]
    client = Client(DOMAIN)
    clock = client.node.create_publisher(Clock, "/clock", 10)
    timer = client.node.create_timer(0.05, lambda: clock.publish(Clock(clock=_time(4242, 5))))
    node = _node(mem, logs["node"], "--params-file", str(params))
    try:
        goals = client.collect(PoseStamped, "/goal_pose")
        diag = client.collect(DiagnosticArray, "/diagnostics")
        sent = _publish("--frames", "30", "--mode", "compressed", "--second-camera", "camera2/image_raw")
        wait_for(
            lambda: (
                _diag(diag).get("received") == str(sent["images"])
                and _diag(diag).get("waiting for a pose") == "0"
                and _diag(diag).get("queue depth") == "0"
            ),
            120,
            "the node to settle every frame",
            show=lambda: (sent, _diag(diag)),
        )
        assert "images: compressed on /camera/image_raw/compressed" in logs["node"].read_text()
        drive = client.call(Ask, "/ravenmem/ask", Ask.Request(question="where is the desk?", navigate=True))
        assert drive.found and drive.reason == "", drive.reason  # type: ignore[attr-defined]
        answer = json.loads(drive.answer_json)  # type: ignore[attr-defined]
        assert answer["drive"]["status"] == "succeeded" and answer["drive"]["feedback"] == 3
        assert drive.goal.header.stamp.sec == 4242  # type: ignore[attr-defined]  # ROS (simulated) time
        got = [json.loads(ln) for ln in nav_goals.read_text().splitlines()]
        assert len(got) == 1 and got[0]["frame_id"] == "odom" and int(got[0]["stamp"]) == 4242
        assert goals == []  # with navigate_action, the goal goes through the action only

        action = ActionClient(client.node, AskAction, "/ravenmem/ask_action")
        assert action.wait_for_server(timeout_sec=30)
        done, _ = _ask_by_action(action, AskAction.Goal(question="where is the desk?"))
        assert done.result.found and done.result.goal.header.frame_id == ""
        assert len(got) == 1  # an action without navigate drives nowhere

        # canceled while the robot drives there: the question ends canceled, and so does the drive
        started = action.send_goal_async(AskAction.Goal(question="where is the desk?", navigate=True))
        wait_for(lambda: started.done(), 60, "the action to accept the second goal")
        wait_for(lambda: len(nav_goals.read_text().splitlines()) >= 2, 60, "the second drive to start")
        started.result().cancel_goal_async()
        ended = started.result().get_result_async()
        wait_for(lambda: ended.done(), 60, "the canceled question's result")
        assert (
            ended.result().status == GoalStatus.STATUS_CANCELED and ended.result().result.reason == "canceled"
        )
        wait_for(lambda: '"canceled": true' in nav_goals.read_text(), 30, "NavigateToPose to be canceled")
        assert goals == []
    finally:
        timer.cancel()
        client.close()
        text = stop(node, logs["node"], sig=signal.SIGINT)  # Ctrl-C: the same clean stop
        for p, k in zip(peers, ("map", "nav"), strict=True):
            stop(p, logs[k])
    assert node.returncode == 0, text[-3000:]
    assert "Traceback" not in text, text[-3000:]
    run = _ingest(mem)["counts"]
    assert run["received"] == sent["images"]
    assert run["stored"] + sum(run["skipped"].values()) == run["received"]
    assert run["stored"] >= 2  # keyframes: all; the frames were posed through /tf
    with ravenmem.open(mem) as m:  # two cameras, two keyframe streams
        assert {r.source for r in m.all_records()} == {"ros", "ros:camera2/image_raw"}


def _two_tool_calls_then_answer(body: dict[str, Any]) -> dict[str, Any]:
    """The scripted model: search_text, then search_time, then an answer resting on the first
    memory the text search showed (its id read from the tool result, as a model would)."""
    from tests.agent.scripted_server import answer, tool

    shown = [m["content"] for m in body["messages"] if m["role"] == "tool"]
    if not shown:
        return tool("search_text", query="a desk")
    if len(shown) == 1:
        return tool("search_time", time="+0")
    first = re.search(r"\[m(\d+)\]", shown[0])
    assert first is not None, shown[0]
    return answer(question_type="position", answer="by the desk", evidence=[int(first.group(1))])


def test_images_lost_in_a_burst_are_counted_and_the_action_reports_each_tool_call(
    ros: Path, tmp_path: Path
) -> None:
    from diagnostic_msgs.msg import DiagnosticArray
    from ravenmem_msgs.action import Ask as AskAction
    from rclpy.action import ActionClient
    from rclpy.qos import QoSProfile, ReliabilityPolicy
    from sensor_msgs.msg import Image

    from tests.agent.scripted_server import ScriptedModel

    mem, log = tmp_path / "robot.mem", tmp_path / "node.log"
    with ScriptedModel(default=_two_tool_calls_then_answer) as model:
        # a one-image history: a burst overflows it while the node is busy, and DDS says nothing
        node = _node(
            mem,
            log,
            *("-p", "image_qos:=reliable", "-p", "image_transport:=raw", "-p", "image_depth:=1"),
            *("-p", "keyframes:=all", "-p", "diagnostics_period:=0.5"),
            *("-p", "model:=scripted", "-p", f"base_url:={model.base_url}"),
        )
        client = Client(DOMAIN)
        try:
            diag = client.collect(DiagnosticArray, "/diagnostics")
            plain = client.count(
                Image, "/camera/image_raw", QoSProfile(depth=1000, reliability=ReliabilityPolicy.RELIABLE)
            )
            # 58 frames as fast as they go between two sent a second apart: a gap shows between
            # two images the node received from the same publisher
            sent = _publish("--frames", "60", "--mode", "raw", "--rate", "1000", "--alone", "1")

            def seen() -> int:
                d = _diag(diag)
                return int(d.get("received", 0)) + int(d.get("lost in transport", 0))

            # every image sent: received by the node, or counted lost (a gap in the sequence)
            wait_for(
                lambda: (
                    seen() == sent["images"]
                    and _diag(diag).get("queue depth") == "0"
                    and _diag(diag).get("waiting for a pose") == "0"
                ),
                120,
                "the node to account for every image",
                show=lambda: (sent, plain, _diag(diag)),
            )
            d = _diag(diag)
            assert int(d["lost in transport"]) >= 1 and int(d["received"]) < sent["images"], d
            assert plain[0] <= seen()  # so every image a plain subscriber got, too
            assert int(d["stored"]) + int(d["skipped"]) == int(d["received"]) and int(d["stored"]) >= 2

            action = ActionClient(client.node, AskAction, "/ravenmem/ask_action")
            assert action.wait_for_server(timeout_sec=30)
            done, feedback = _ask_by_action(action, AskAction.Goal(question="where is the desk?"))
            result = done.result
        finally:
            client.close()
            text = stop(node, log)
    assert node.returncode == 0, text[-3000:]
    assert result.found and result.answer == "by the desk", result.reason
    cost = json.loads(result.answer_json)["cost"]
    calls = [f.feedback for f in feedback if f.feedback.step > 0]
    # one feedback per tool call the answer records, in order, as the agent reported each
    assert len(calls) == cost["tool_calls"] == 2 and cost["tool_calls_rejected"] == 0
    assert [(c.step, c.tool, c.ok) for c in calls] == [(1, "search_text", True), (2, "search_time", True)]
    assert json.loads(calls[0].arguments) == {"query": "a desk"}
    assert calls[0].hits >= 2 and calls[0].stage == f"search_text: {calls[0].hits} memories"
    assert len(model.requests) == 3  # the model was asked three times: two tool calls, the answer


def _time(sec: int, nanosec: int) -> Any:
    from builtin_interfaces.msg import Time

    return Time(sec=sec, nanosec=nanosec)


def test_a_bad_parameter_is_one_line_and_exit_2(ros: Path, tmp_path: Path) -> None:
    from tests.cli.helpers import assert_one_line_error, run_cli

    r = run_cli(
        "ros",
        "run",
        "--memory",
        str(tmp_path / "m.mem"),
        "--create",
        "--ros-args",
        "-p",
        "image_transport:=jpeg",
        env=graph_env(DOMAIN),
        timeout=120,
    )
    line = assert_one_line_error(r)
    assert "image_transport" in line and "jpeg" in line
    assert not (tmp_path / "m.mem").exists()  # nothing created for a run that cannot start
    # an argument rcl itself cannot parse: the same one line
    r = run_cli(
        "ros",
        "run",
        "--memory",
        str(tmp_path / "m.mem"),
        "--create",
        "--ros-args",
        "-p",
        "keyframes:=",
        env=graph_env(DOMAIN),
        timeout=120,
    )
    assert "--ros-args" in assert_one_line_error(r)
