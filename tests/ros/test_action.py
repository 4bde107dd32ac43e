"""Driving with Nav2's NavigateToPose over Zenoh, against a scripted action server on loopback that
speaks the keys zenoh-bridge-ros2dds gives the action (`navigate_to_pose/_action/...`) with the
action's CDR types: send goal, feedback, result, cancel; and `ravenmem_msgs/srv/Ask` with
navigate, whose answer reports how the drive went."""

from __future__ import annotations

import json
import threading
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

import ravenmem
from ravenmem.nav.goals import pose_stamped, read_pose_stamped
from ravenmem.ros import action as act
from ravenmem.ros import msgs
from ravenmem.ros.link import LinkConfig
from ravenmem.ros.services import register
from ravenmem.ros.zenoh import ZenohEndpoints, start_link
from ravenmem.runtime.ask import AskArgs
from ravenmem.runtime.service import Service, ServiceConfig
from tests.agent.test_ask_navigate import with_map
from tests.conftest import ColorEmbedder
from tests.ros.test_zenoh_loopback import free_port, peer, wait_until

zenoh: Any = pytest.importorskip("zenoh", reason="the robot extra (eclipse-zenoh) is not installed")
A = act.ACTION


class ScriptedNav2:
    """A NavigateToPose server: accepts goals (unless told not to), sends `feedback` messages,
    answers get_result with SUCCEEDED, or CANCELED once a cancel came (with `wait_for_cancel`)."""

    def __init__(
        self, session: Any, accept: bool = True, feedback: int = 3, wait_for_cancel: bool = False
    ) -> None:
        self.session, self.accept, self.n_feedback, self.wait_for_cancel = (
            session,
            accept,
            feedback,
            wait_for_cancel,
        )
        self.goals: list[dict[str, Any]] = []
        self.canceled = threading.Event()
        k = act.keys("navigate_to_pose")
        self.feedback_pub = session.declare_publisher(k["feedback"])
        self.qs = [
            session.declare_queryable(k["send_goal"], self._send_goal),
            session.declare_queryable(k["get_result"], self._get_result),
            session.declare_queryable(k["cancel_goal"], self._cancel),
        ]

    def _send_goal(self, q: Any) -> None:
        req = act.decode(q.payload.to_bytes(), f"{A}_SendGoal_Request")
        self.goals.append(req)
        q.reply(
            q.key_expr,
            act.cdr({"accepted": self.accept, "stamp": {"sec": 1, "nanosec": 0}}, f"{A}_SendGoal_Response"),
        )

    def _get_result(self, q: Any) -> None:
        goal_id = act.decode(q.payload.to_bytes(), f"{A}_GetResult_Request")["goal_id"]["uuid"]

        def run() -> None:
            for i in range(self.n_feedback):
                fb = {"goal_id": {"uuid": list(goal_id)}, "feedback": {"distance_remaining": 3.0 - i}}
                self.feedback_pub.put(act.cdr(fb, f"{A}_FeedbackMessage"))
            status = 4
            if self.wait_for_cancel:
                self.canceled.wait(30)
                status = 5
            wait_until(lambda: False, 0.2)  # the feedback arrives before the result
            result = {"status": status, "result": {"error_code": 0, "error_msg": ""}}
            q.reply(q.key_expr, act.cdr(result, f"{A}_GetResult_Response"))
            q.drop()

        threading.Thread(target=run, daemon=True).start()

    def _cancel(self, q: Any) -> None:
        req = act.decode(q.payload.to_bytes(), "action_msgs/srv/CancelGoal_Request")
        self.canceled.set()
        reply = {"return_code": 0, "goals_canceling": [req["goal_info"]]}
        q.reply(q.key_expr, act.cdr(reply, "action_msgs/srv/CancelGoal_Response"))

    def close(self) -> None:
        for q in self.qs:
            q.undeclare()


@pytest.fixture
def pair() -> Iterator[tuple[Any, Any]]:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    robot, us = peer(endpoint, listen=True), peer(endpoint)
    yield robot, us
    us.close()
    robot.close()


def test_drive_sends_the_goal_follows_feedback_and_reports_the_result(pair: tuple[Any, Any]) -> None:
    robot, us = pair
    server = ScriptedNav2(robot)
    client = act.NavigateClient(us, "navigate_to_pose")
    goal = pose_stamped(1.5, -2.0, 0.7, frame_id="odom")
    assert wait_until(
        lambda: bool(list(us.get(act.keys("navigate_to_pose")["cancel_goal"], timeout=1.0))), 10
    )
    out = client.drive(goal)
    assert out["accepted"] and out["status"] == "succeeded" and out["status_code"] == 4, out
    assert out["feedback"] == 3 and out["distance_remaining"] == pytest.approx(1.0)
    (sent,) = server.goals[-1:]
    assert msgs.to_dict(msgs.to_message(sent["goal"]["pose"], msgs.POSE_STAMPED)) == msgs.to_dict(
        msgs.to_message(goal, msgs.POSE_STAMPED)
    )  # the plan's PoseStamped, in the memory's frame
    assert bytes(sent["goal_id"]["uuid"]).hex() == out["goal_id"]
    server.accept = False
    assert client.drive(goal)["status"] == "rejected"
    client.close()


def test_a_goal_can_be_cancelled(pair: tuple[Any, Any]) -> None:
    robot, us = pair
    server = ScriptedNav2(robot, wait_for_cancel=True)
    client = act.NavigateClient(us, "navigate_to_pose")
    results: list[dict[str, Any]] = []
    th = threading.Thread(target=lambda: results.append(client.drive(pose_stamped(1, 1, 0))))
    th.start()
    assert wait_until(lambda: bool(server.goals), 10)
    reply = client.cancel()
    assert reply["return_code"] == 0 and reply["canceling"] == 1
    th.join(30)
    assert results and results[0]["status"] == "canceled"
    client.close()


def test_no_action_server_is_said_not_raised(pair: tuple[Any, Any]) -> None:
    _, us = pair
    client = act.NavigateClient(us, "nobody_home", send_timeout=0.5)
    out = client.drive(pose_stamped(0, 0, 0))
    assert out["status"] == "no action server" and "send_goal" in out["error"]
    client.close()


def test_srv_ask_with_navigate_drives_and_reports_the_result(mem_path: Path) -> None:
    """The memory's service over Zenoh, its link configured with the action: a robot asks with
    navigate, Nav2 drives, the reply's answer says how it went."""
    with_map(mem_path)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    robot = peer(endpoint, listen=True)
    server = ScriptedNav2(robot)
    service = Service(ravenmem.open(mem_path, embedder=ColorEmbedder()), ServiceConfig(method="offline"))
    cfg = LinkConfig.from_spec("image=camera,pose=odom,action=navigate_to_pose")
    link = start_link(service, cfg, ZenohEndpoints(connect=(endpoint,)))
    try:
        register()
        req = {"question": "Where did I leave the magenta box?", "navigate": True}
        raw = msgs.serialize(
            msgs.to_message(req, "ravenmem_msgs/srv/Ask_Request"), "ravenmem_msgs/srv/Ask_Request"
        )
        assert wait_until(lambda: bool(list(robot.get("ravenmem/ask", payload=b"", timeout=5.0))), 30)
        (reply,) = [r.ok for r in robot.get("ravenmem/ask", payload=raw, timeout=60.0) if r.ok is not None]
        ans = msgs.to_dict(msgs.deserialize(reply.payload.to_bytes(), "ravenmem_msgs/srv/Ask_Response"))
        data = json.loads(ans["answer_json"])
        assert ans["found"] and ans["reason"] == "" and data["drive"]["status"] == "succeeded"
        assert read_pose_stamped(server.goals[-1]["goal"]["pose"])[:3] == pytest.approx(
            read_pose_stamped(ans["goal"])[:3]
        )
        assert link.describe()["last_drive"]["status"] == "succeeded"
        # an answer from elsewhere (POST /ask, MCP) with a plan: the link drives in the background
        n = len(server.goals)
        result = service.ask(AskArgs(question="Where did I leave the magenta box?", navigate=True))
        assert (
            result.drive is None and result.goal is not None
        )  # asked without a drive: the link's hook drives
        assert wait_until(
            lambda: link.describe()["last_drive"]["status"] == "succeeded" and len(server.goals) == n + 1, 30
        )
        server.accept = False  # Nav2 refuses: the reply says the robot did not get there
        (reply,) = [r.ok for r in robot.get("ravenmem/ask", payload=raw, timeout=60.0) if r.ok is not None]
        ans = msgs.to_dict(msgs.deserialize(reply.payload.to_bytes(), "ravenmem_msgs/srv/Ask_Response"))
        assert ans["found"] and "did not get there: NavigateToPose rejected" in ans["reason"]
    finally:
        service.close()
        server.close()
        robot.close()
