"""Driving to a goal with Nav2's `NavigateToPose` action over Zenoh, as zenoh-bridge-ros2dds maps
ROS 2 actions: an action `/navigate_to_pose` is three services and two topics under
`navigate_to_pose/_action/`: `send_goal`, `get_result`, `cancel_goal` (queryables) and
`feedback`, `status` (publications), each with the CDR of the action's generated types
(`NavigateToPose_SendGoal_Request` = goal id + goal, ...).

`NavigateClient.drive(goal)` sends the goal (the PoseStamped of a `nav.goals` plan, in the
memory's frame), follows its feedback, and waits for the result; `cancel()` cancels the goal
being driven to. The types are Nav2's as of ROS 2 Jazzy (the result carries `error_code` and
`error_msg`); a Humble Nav2's result (an empty message) is read for its status alone.
"""

from __future__ import annotations

import contextlib
import logging
import math
import threading
import time
import uuid
from typing import Any

from ..errors import InputError
from . import msgs

log = logging.getLogger(__name__)

ACTION = "nav2_msgs/action/NavigateToPose"
STATUS = {
    0: "unknown",
    1: "accepted",
    2: "executing",
    3: "canceling",
    4: "succeeded",
    5: "canceled",
    6: "aborted",
}
CANCEL_CODES = {0: "cancelling", 1: "rejected", 2: "unknown goal", 3: "goal terminated"}

_TYPES = {
    f"{ACTION}_Goal": "geometry_msgs/PoseStamped pose\nstring behavior_tree\n",
    f"{ACTION}_Result": "uint16 error_code\nstring error_msg\n",
    f"{ACTION}_Feedback": (
        "geometry_msgs/PoseStamped current_pose\nbuiltin_interfaces/Duration navigation_time\n"
        "builtin_interfaces/Duration estimated_time_remaining\nint16 number_of_recoveries\n"
        "float32 distance_remaining\n"
    ),
    f"{ACTION}_SendGoal_Request": f"unique_identifier_msgs/UUID goal_id\n{ACTION.replace('/action/', '/')}_Goal goal\n",
    f"{ACTION}_SendGoal_Response": "bool accepted\nbuiltin_interfaces/Time stamp\n",
    f"{ACTION}_GetResult_Request": "unique_identifier_msgs/UUID goal_id\n",
    f"{ACTION}_GetResult_Response": f"int8 status\n{ACTION.replace('/action/', '/')}_Result result\n",
    f"{ACTION}_FeedbackMessage": f"unique_identifier_msgs/UUID goal_id\n{ACTION.replace('/action/', '/')}_Feedback feedback\n",
    "action_msgs/srv/CancelGoal_Request": "action_msgs/GoalInfo goal_info\n",
    "action_msgs/srv/CancelGoal_Response": "int8 return_code\naction_msgs/GoalInfo[] goals_canceling\n",
}


def register() -> None:
    """Teach the CDR type store NavigateToPose's parts and CancelGoal (idempotent)."""
    # the nested names above (nav2_msgs/NavigateToPose_Goal) resolve to the registered parts
    texts = {name: text.replace("nav2_msgs/NavigateToPose_", f"{ACTION}_") for name, text in _TYPES.items()}
    msgs.register(texts)


def keys(action: str) -> dict[str, str]:
    """The Zenoh keys of an action's services and topics (zenoh-bridge-ros2dds naming)."""
    base = action.strip("/")
    return {
        k: f"{base}/_action/{k}" for k in ("send_goal", "get_result", "cancel_goal", "feedback", "status")
    }


def cdr(data: dict[str, Any], msgtype: str) -> bytes:
    register()
    return msgs.serialize(msgs.to_message(data, msgtype), msgtype)


def decode(raw: bytes, msgtype: str) -> dict[str, Any]:
    register()
    return dict(msgs.to_dict(msgs.deserialize(raw, msgtype)))


class NavigateClient:
    """A NavigateToPose client on an open Zenoh session (see the module docstring)."""

    def __init__(
        self,
        session: Any,
        action: str = "navigate_to_pose",
        send_timeout: float = 10.0,
        result_timeout: float = 600.0,
    ) -> None:
        register()
        self.session = session
        self.keys = keys(action)
        self.send_timeout, self.result_timeout = send_timeout, result_timeout
        self._lock = threading.Lock()
        self._goal_id: bytes | None = None
        self._feedback: dict[str, Any] = {}
        self._sub = session.declare_subscriber(self.keys["feedback"], self._on_feedback)

    def _on_feedback(self, sample: Any) -> None:
        try:
            fb = decode(sample.payload.to_bytes(), f"{ACTION}_FeedbackMessage")
        except Exception:  # another action's feedback, or garbage
            return
        with self._lock:
            if self._goal_id is not None and bytes(fb["goal_id"]["uuid"]) == self._goal_id:
                self._feedback["count"] = self._feedback.get("count", 0) + 1
                self._feedback["distance_remaining"] = float(fb["feedback"]["distance_remaining"])

    def _call(self, key: str, payload: bytes, timeout: float) -> bytes:
        replies = list(self.session.get(key, payload=payload, timeout=timeout))
        for r in replies:
            if r.ok is not None:
                return bytes(r.ok.payload.to_bytes())
        errs = [r.err.payload.to_bytes().decode(errors="replace") for r in replies if r.err is not None]
        raise InputError(f"{key}: no answer from the action server{': ' + errs[0] if errs else ''}")

    def drive(self, goal: dict[str, Any]) -> dict[str, Any]:
        """Send `goal` (PoseStamped JSON), wait for the result; what happened, as a dict (never
        raises for the robot's own failures: `status` says rejected, aborted, ...)."""
        goal_id = uuid.uuid4().bytes
        with self._lock:
            self._goal_id, self._feedback = goal_id, {}
        started = time.monotonic()
        out: dict[str, Any] = {"goal": goal, "goal_id": goal_id.hex()}
        request = {"goal_id": {"uuid": list(goal_id)}, "goal": {"pose": goal, "behavior_tree": ""}}
        try:
            sent = decode(
                self._call(
                    self.keys["send_goal"], cdr(request, f"{ACTION}_SendGoal_Request"), self.send_timeout
                ),
                f"{ACTION}_SendGoal_Response",
            )
            if not sent["accepted"]:
                return out | {"accepted": False, "status": "rejected", "seconds": time.monotonic() - started}
            raw = self._call(
                self.keys["get_result"],
                cdr({"goal_id": {"uuid": list(goal_id)}}, f"{ACTION}_GetResult_Request"),
                self.result_timeout,
            )
        except InputError as e:
            return out | {"accepted": None, "status": "no action server", "error": str(e)}
        code, error = _status_of(raw)
        with self._lock:
            fb, self._goal_id = dict(self._feedback), None
        return (
            out
            | {
                "accepted": True,
                "status": STATUS.get(code, f"status {code}"),
                "status_code": code,
                "feedback": fb.get("count", 0),
                "distance_remaining": fb.get("distance_remaining"),
                "seconds": round(time.monotonic() - started, 3),
            }
            | error
        )

    def cancel(self) -> dict[str, Any]:
        """Cancel the goal being driven to (none: every goal of this action, as ROS 2 does for a
        zero goal id). Returns the server's answer."""
        with self._lock:
            goal_id = self._goal_id or bytes(16)
        now = time.time()
        sec = int(math.floor(now))
        info = {"goal_id": {"uuid": list(goal_id)}, "stamp": {"sec": sec, "nanosec": int((now - sec) * 1e9)}}
        raw = self._call(
            self.keys["cancel_goal"],
            cdr({"goal_info": info}, "action_msgs/srv/CancelGoal_Request"),
            self.send_timeout,
        )
        reply = decode(raw, "action_msgs/srv/CancelGoal_Response")
        return {
            "return_code": int(reply["return_code"]),
            "meaning": CANCEL_CODES.get(int(reply["return_code"]), "?"),
            "canceling": len(reply["goals_canceling"]),
        }

    def close(self) -> None:
        with contextlib.suppress(Exception):
            self._sub.undeclare()


def _status_of(raw: bytes) -> tuple[int, dict[str, Any]]:
    """The result's status, and its error code and message when it has them (Jazzy's Nav2)."""
    try:
        res = decode(raw, f"{ACTION}_GetResult_Response")
        return int(res["status"]), {
            "error_code": int(res["result"]["error_code"]),
            "error_msg": res["result"]["error_msg"],
        }
    except Exception:  # another distro's result: the status is the first byte after the CDR header
        if len(raw) < 5:
            return 0, {}
        return int.from_bytes(raw[4:5], "little", signed=True), {}
