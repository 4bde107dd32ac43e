"""One question, every front end, one goal: `ravenmem ask --navigate`, `ravenmem navigate`,
`POST /ask` with navigate, MCP `ask`, `ravenmem_msgs/srv/Ask` over Zenoh (both key conventions)
with the goal published on /goal_pose, and the ROS 2 node's logic (rclpy itself cannot run
here). All plan with `nav.goals.goal_for`, so the goals are the same, and all are in the
memory's frame, here `odom` (a memory whose poses had no map frame): no front end publishes a
goal in any other frame.

The ROS 2 client is played by a Zenoh peer on loopback that serialises its requests with
`rosbags`, the service types registered from the `ravenmem_msgs/srv/*.srv` text a ROS 2 user
builds; the service is the real `ravenmem serve --zenoh` in a subprocess."""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

import anyio
import httpx
import numpy as np
import pytest
from mcp import Client
from rosbags.typesys import Stores, get_types_from_msg, get_typestore

import ravenmem
from ravenmem.nav.goals import read_pose_stamped
from ravenmem.ros.services import interface_dir, rmw_request_attachment
from tests.agent.conftest import run_cli
from tests.agent.test_ask_navigate import with_map
from tests.ros.test_zenoh_loopback import free_port, peer, wait_until
from tests.server.conftest import serve_subprocess, stop

zenoh: Any = pytest.importorskip("zenoh", reason="the robot extra (eclipse-zenoh) is not installed")

QUESTION = "Where did I leave the magenta box?"
MAP_ID = "lab-1"


def client_types() -> Any:
    """A ROS 2 client's type store: rosbags' own, plus ravenmem_msgs from the .srv/.msg files."""
    ts = get_typestore(Stores.ROS2_HUMBLE)
    root = Path(str(interface_dir()))
    new: dict[str, Any] = {}
    new |= get_types_from_msg((root / "msg" / "Memory.msg").read_text(), "ravenmem_msgs/msg/Memory")
    for srv in ("Ask", "Search"):
        req, _, res = (root / "srv" / f"{srv}.srv").read_text().partition("\n---")
        for part, text in (("Request", req), ("Response", res)):
            name = f"ravenmem_msgs/srv/{srv}_{part}"
            new[name] = next(iter(get_types_from_msg(text, name).values()))
    ts.register(new)
    return ts


def ask_request(ts: Any, question: str, navigate: bool) -> bytes:
    T = ts.types
    stamp = T["builtin_interfaces/msg/Time"](sec=0, nanosec=0)
    header = T["std_msgs/msg/Header"](stamp=stamp, frame_id="")
    image = T["sensor_msgs/msg/Image"](
        header=header, height=0, width=0, encoding="", is_bigendian=0, step=0, data=np.zeros(0, np.uint8)
    )
    req = T["ravenmem_msgs/srv/Ask_Request"](question=question, image=image, navigate=navigate)
    return bytes(ts.serialize_cdr(req, "ravenmem_msgs/srv/Ask_Request"))


def call(robot: Any, key: str, payload: bytes, attachment: bytes | None = None) -> tuple[bytes, bytes | None]:
    """One query, one reply (payload, attachment), as a ROS 2 client's call over Zenoh."""
    kw = {"attachment": attachment} if attachment is not None else {}
    replies = list(robot.get(key, payload=payload, timeout=90.0, **kw))
    oks = [r.ok for r in replies if r.ok is not None]
    assert len(oks) == 1, [str(r.err.payload.to_bytes()) for r in replies if r.err is not None]
    att = oks[0].attachment
    return oks[0].payload.to_bytes(), (att.to_bytes() if att is not None else None)


def xyyaw(pose_stamped: dict[str, Any]) -> tuple[float, float, float, str]:
    return read_pose_stamped(pose_stamped)


@pytest.fixture
def cli(color_plugin, tmp_path):
    home = tmp_path / "home"
    return lambda *args, **kw: run_cli(*args, site=color_plugin, home=home, **kw)


def test_every_front_end_gives_the_same_goal_in_the_memorys_frame(cli, mem_path: Path) -> None:
    with_map(mem_path)
    with ravenmem.open(mem_path) as mem:
        mem.claim_map(MAP_ID, "odom")  # poses of a robot without a map frame (REP 105: odom)
    goals: dict[str, tuple[float, float, float, str]] = {}

    r = cli("ask", QUESTION, "-m", str(mem_path), "--offline", "--navigate", "--json")
    assert r.returncode == 0, r.stderr
    data = json.loads(r.stdout)
    assert (data["frame_id"], data["map_id"]) == ("odom", MAP_ID)  # every answer says where it is
    nav = data["navigation"]
    assert nav["ok"] and (nav["frame_id"], nav["map_id"]) == ("odom", MAP_ID)
    assert nav["heading"]["source"] == "evidence"  # the offline answer has no yaw of its own
    goals["ask --navigate"] = xyyaw(nav["pose_stamped"])
    reference = {k: nav[k] for k in ("goal", "heading", "pose_stamped", "waypoints", "frame_id", "map_id")}

    r = cli("navigate", "-m", str(mem_path), "--to", QUESTION, "--method", "offline", "--json")
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert {k: out[k] for k in reference} == reference  # the same plan, in the same JSON shape
    goals["navigate"] = xyyaw(out["pose_stamped"])

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    robot = peer(endpoint, listen=True)
    published: list[bytes] = []
    robot.declare_subscriber("goal_pose", lambda s: published.append(s.payload.to_bytes()))
    proc, url = serve_subprocess(
        mem_path, "--zenoh", "image=camera,pose=odom,goal=goal_pose", "--zenoh-connect", endpoint
    )
    ts = client_types()
    try:
        info = httpx.get(url + "/info", timeout=30).json()
        assert (info["frame_id"], info["map_id"]) == ("odom", MAP_ID)
        r = httpx.post(
            url + "/ask", json={"question": QUESTION, "method": "offline", "navigate": True}, timeout=90
        )
        assert r.status_code == 200, r.text
        nav = r.json()["navigation"]
        assert {k: nav[k] for k in reference} == reference
        goals["POST /ask"] = xyyaw(nav["pose_stamped"])
        # the answer went to the robot link too: its plan's goal, on /goal_pose
        assert wait_until(lambda: len(published) == 1, 30)
        goals["/goal_pose after POST /ask"] = xyyaw(_as_dict(ts, published[0]))

        async def mcp_ask() -> dict[str, Any]:
            async with Client(f"{url}/mcp", read_timeout_seconds=90) as client:
                res = await client.call_tool(
                    "ask", {"question": QUESTION, "method": "offline", "navigate": True}
                )
                assert not res.is_error, res.content
                return dict(res.structured_content or {})

        mcp_data = anyio.run(mcp_ask)
        assert wait_until(lambda: len(published) == 2, 30)  # every answer goes to the robot link
        assert {k: mcp_data["navigation"][k] for k in reference} == reference
        assert mcp_data["map_id"] == MAP_ID
        goals["MCP ask"] = xyyaw(mcp_data["navigation"]["pose_stamped"])

        # ravenmem_msgs/srv/Ask over Zenoh, as zenoh-bridge-ros2dds routes `ros2 service call`
        assert wait_until(lambda: bool(list(robot.liveliness().get("@/*/@ros2_lv/SS/**", timeout=2.0))), 30)
        tokens = [
            str(r.ok.key_expr) for r in robot.liveliness().get("@/*/@ros2_lv/SS/**", timeout=5.0) if r.ok
        ]
        assert any(t.endswith("/SS/ravenmem§ask/ravenmem_msgs§srv§Ask") for t in tokens), tokens
        raw, _ = call(robot, "ravenmem/ask", ask_request(ts, QUESTION, True), attachment=bytes(16))
        reply = ts.deserialize_cdr(raw, "ravenmem_msgs/srv/Ask_Response")
        assert reply.found and not reply.unsupported and reply.reason == "" and reply.map_id == MAP_ID
        assert "magenta" in reply.answer.lower() or json.loads(reply.answer_json)["position"] == [
            7.0,
            3.0,
            0.5,
        ]
        assert json.loads(reply.answer_json)["navigation"]["pose_stamped"] == reference["pose_stamped"]
        goals["srv/Ask via the bridge key"] = _goal(reply)
        # ... and as rmw_zenoh names the service, with its attachment echoed
        key = "0/ravenmem/ask/ravenmem_msgs::srv::dds_::Ask_/RIHS01_" + "0" * 64
        raw, att = call(robot, key, ask_request(ts, QUESTION, True), rmw_request_attachment(41, b"G" * 16))
        assert (
            att is not None
            and len(att) == 32
            and att[:8] == (41).to_bytes(8, "little")
            and att[16:] == b"G" * 16
        )
        goals["srv/Ask via the rmw_zenoh key"] = _goal(
            ts.deserialize_cdr(raw, "ravenmem_msgs/srv/Ask_Response")
        )
        # the service's questions went to the robot's goal topic as well
        assert wait_until(lambda: len(published) == 4, 30)
        goals["/goal_pose after srv/Ask"] = xyyaw(_as_dict(ts, published[-1]))
        # a question without navigate: an answer, no goal in the reply; the link, which sends
        # every answer with a position to the goal topic, plans it there (goal_for again)
        raw, _ = call(robot, "ravenmem/ask", ask_request(ts, QUESTION, False))
        plain = ts.deserialize_cdr(raw, "ravenmem_msgs/srv/Ask_Response")
        assert plain.found and plain.goal.header.frame_id == "" and plain.reason == ""
        assert wait_until(lambda: len(published) == 5, 30)
        goals["/goal_pose planned by the link"] = xyyaw(_as_dict(ts, published[-1]))
        # Search: memories with pose, time and score, in the memory's frame
        search = ts.types["ravenmem_msgs/srv/Search_Request"](
            tool="text", query="magenta", k=2, after="", before="", near=np.zeros(0)
        )
        raw, _ = call(
            robot, "ravenmem/search", bytes(ts.serialize_cdr(search, "ravenmem_msgs/srv/Search_Request"))
        )
        found = ts.deserialize_cdr(raw, "ravenmem_msgs/srv/Search_Response")
        assert found.error == "" and len(found.memories) == 2
        best = found.memories[0]
        assert best.pose.header.frame_id == "odom" and (
            best.pose.pose.position.x,
            best.pose.pose.position.y,
        ) == (7.0, 3.0)
        assert best.score > found.memories[1].score and best.pose.header.stamp.sec > 1_600_000_000
        links = httpx.get(url + "/info", timeout=30).json()["links"]
        assert links[0]["questions"] == 4 and links[0]["goals"] == 5
    finally:
        stop(proc)
        robot.close()

    # the ROS 2 node's logic (rclpy cannot run here): the same replies and goals
    from ravenmem.ros.link import LinkConfig
    from ravenmem.ros.node import NodeLogic
    from ravenmem.runtime.ask import AskArgs
    from ravenmem.runtime.service import Service, ServiceConfig
    from tests.conftest import ColorEmbedder

    service = Service(
        ravenmem.open(mem_path, embedder=ColorEmbedder()), ServiceConfig(method="offline")
    ).start()
    try:
        logic = NodeLogic(LinkConfig.from_spec("image=camera,pose=odom,goal=goal_pose"), service)
        reply_d = logic.ask({"question": QUESTION, "navigate": True})
        assert reply_d["found"] and reply_d["map_id"] == MAP_ID
        goals["node: srv/Ask"] = xyyaw(reply_d["goal"])
        result = service.ask(AskArgs(question=QUESTION))
        assert result.plan is None
        payload = logic.goal(result)  # an answer without a plan: the node plans it (goal_for)
        assert payload is not None
        goals["node: /goal_pose"] = xyyaw(_as_dict(ts, payload))
    finally:
        service.close()

    first = goals["ask --navigate"]
    assert first[3] == "odom"
    for name, g in goals.items():
        assert g[3] == "odom", name
        assert g[:3] == pytest.approx(first[:3], abs=1e-9), name
    assert math.dist(first[:2], (7.0, 3.0)) < 0.1  # where the magenta box was seen


def _as_dict(ts: Any, raw: bytes) -> dict[str, Any]:
    from ravenmem.ros.msgs import to_dict

    return to_dict(ts.deserialize_cdr(raw, "geometry_msgs/msg/PoseStamped"))


def _goal(reply: Any) -> tuple[float, float, float, str]:
    from ravenmem.ros.msgs import to_dict

    return xyyaw(to_dict(reply.goal))
