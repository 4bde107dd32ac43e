"""`~/ask_action` (`ravenmem_msgs/action/Ask`): a question as a ROS 2 action. A model's answer
takes seconds, so the client gets feedback (the stage and the time it has taken, every half
second) and may cancel. The answer runs on a worker thread (`ros.services.ask_reply`, the same
reply as the service); a canceled goal ends at once, the NavigateToPose goal it sent (if any) is
canceled too, and its answer, when it comes, is dropped: no goal is published for it."""

from __future__ import annotations

import threading
import time
from typing import TYPE_CHECKING, Any

from .convert import fill, to_dict
from .services import ask_reply

if TYPE_CHECKING:
    from .node import RavenmemNode

FEEDBACK_S = 0.5


class AskAction:
    def __init__(self, owner: RavenmemNode, group: Any) -> None:
        from ravenmem_msgs.action import Ask
        from rclpy.action import ActionServer, CancelResponse

        self.owner = owner
        self.cls = Ask
        self.server = ActionServer(
            owner.node,
            Ask,
            "~/ask_action",
            self._execute,
            callback_group=group,
            cancel_callback=lambda _req: CancelResponse.ACCEPT,
        )

    def _execute(self, handle: Any) -> Any:
        request = to_dict(handle.request)
        started = time.monotonic()
        box: dict[str, Any] = {}
        done = threading.Event()

        dropped = threading.Event()  # set once canceled (the handle's own flag clears when it ends)

        def work() -> None:
            self.owner._local.canceled = lambda: dropped.is_set() or handle.is_cancel_requested
            try:
                box["reply"] = ask_reply(self.owner.backend, request)
            finally:
                self.owner._local.canceled = None
                done.set()

        threading.Thread(target=work, name="ravenmem-ask-action", daemon=True).start()
        stage = "planning a path" if request.get("navigate") else "searching memory"
        while not done.wait(FEEDBACK_S):
            if handle.is_cancel_requested:
                navigator = self.owner.navigator
                dropped.set()
                if navigator is not None and request.get("navigate"):
                    navigator.cancel()  # the drive this question started stops too
                handle.canceled()
                return fill(self.cls.Result(), {"found": False, "reason": "canceled"})
            handle.publish_feedback(self.cls.Feedback(stage=stage, elapsed=time.monotonic() - started))
        result = fill(self.cls.Result(), box.get("reply") or {"reason": "no answer"})
        if result.goal.header.frame_id:
            result.goal.header.stamp = self.owner.stamp()
        if handle.is_cancel_requested:
            dropped.set()
            handle.canceled()
            result.reason = "canceled"
        else:
            handle.succeed()
        return result
