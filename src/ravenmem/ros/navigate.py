"""Driving to an answer's goal with Nav2's `NavigateToPose` action over rclpy (`nav2_msgs`, from
a ROS 2 distribution or built by `ravenmem ros setup`). The same result shape as the Zenoh
client (`ros.action.NavigateClient.drive`): `status` says succeeded, aborted, rejected, ..."""

from __future__ import annotations

import threading
import time
from typing import Any

from .action import STATUS
from .convert import fill

SERVER_WAIT_S = 5.0
RESULT_WAIT_S = 600.0


class Navigator:
    """A NavigateToPose client; `drive(goal)` blocks the calling thread (an executor thread of
    a reentrant group) while the executor's other threads deliver the replies and feedback."""

    def __init__(self, node: Any, action: str, group: Any) -> None:
        from nav2_msgs.action import NavigateToPose
        from rclpy.action import ActionClient

        self.node = node
        self.cls = NavigateToPose
        self.client: Any = ActionClient(node, NavigateToPose, action, callback_group=group)
        self.last: dict[str, Any] = {}
        self.active: Any = None  # the goal being driven to (its ClientGoalHandle)

    def drive(self, goal: dict[str, Any]) -> dict[str, Any]:
        started = time.monotonic()
        out: dict[str, Any] = {"goal": goal}
        if not self.client.wait_for_server(timeout_sec=SERVER_WAIT_S):
            return out | {"accepted": None, "status": "no action server"}
        msg = self.cls.Goal()
        fill(msg.pose, goal)
        msg.pose.header.stamp = self.node.get_clock().now().to_msg()
        feedback: dict[str, Any] = {"count": 0, "distance_remaining": None}

        def on_feedback(fb: Any) -> None:
            feedback["count"] += 1
            feedback["distance_remaining"] = float(fb.feedback.distance_remaining)

        handle = _wait(self.client.send_goal_async(msg, feedback_callback=on_feedback), SERVER_WAIT_S)
        if handle is None or not handle.accepted:
            return out | {"accepted": False if handle is not None else None, "status": "rejected"}
        self.active = handle
        try:
            res = _wait(handle.get_result_async(), RESULT_WAIT_S)
        finally:
            self.active = None
        if res is None:
            return out | {"accepted": True, "status": "no result in time"}
        status = int(res.status)
        self.last = out | {
            "accepted": True,
            "status": STATUS.get(status, f"status {status}"),
            "status_code": status,
            "error_code": int(getattr(res.result, "error_code", 0)),
            "error_msg": str(getattr(res.result, "error_msg", "")),
            "feedback": feedback["count"],
            "distance_remaining": feedback["distance_remaining"],
            "seconds": round(time.monotonic() - started, 3),
        }
        self.node.get_logger().info(f"NavigateToPose: {self.last['status']}")
        return self.last

    def cancel(self) -> bool:
        """Cancel the goal being driven to (the question that sent it was canceled); False
        when there is none."""
        handle = self.active
        if handle is None:
            return False
        handle.cancel_goal_async()
        return True


def _wait(future: Any, timeout: float) -> Any:
    """An rclpy future's result, waited for without spinning (other threads spin)."""
    done = threading.Event()
    future.add_done_callback(lambda _f: done.set())
    if not done.wait(timeout):
        return None
    return future.result()
