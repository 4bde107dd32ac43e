"""`~/ask_action` (`ravenmem_msgs/action/Ask`): a question as a ROS 2 action. A model's answer
takes seconds and several tool calls, so the client gets one feedback per tool call as it ends
(`step`, `tool`, `arguments`, `ok`, `hits`: the `agent.progress.ToolStep` the agent reports),
a feedback with `step` 0 every second nothing else happened (the stage and the time taken), and
may cancel. The answer runs on a worker thread (`ros.services.ask_reply`, the same reply as the
service); its tool calls come back through a queue and are published from the action's own
thread. A canceled goal ends at once, the NavigateToPose goal it sent (if any) is canceled too,
and its answer, when it comes, is dropped: no goal is published for it."""

from __future__ import annotations

import queue
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any, Protocol

from ..agent.progress import ToolStep
from .convert import fill, to_dict
from .services import ServiceBackend, ask_reply

if TYPE_CHECKING:
    from .navigate import Navigator

HEARTBEAT_S = 1.0  # a feedback at least this often while the answer runs
POLL_S = 0.1  # how soon a cancel request is noticed


class Host(Protocol):
    """What the action uses of the node that serves it (`ros.node.RavenmemNode`)."""

    node: Any
    backend: ServiceBackend
    navigator: Navigator | None

    def stamp(self) -> Any: ...

    def drop_answers_on_this_thread(self, canceled: Callable[[], bool] | None) -> None:
        """While `canceled()` is true, answers given on this thread publish nothing."""


class AskAction:
    def __init__(self, owner: Host, group: Any) -> None:
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
        steps: queue.Queue[ToolStep | None] = queue.Queue()  # None: the answer is done
        dropped = threading.Event()  # set once canceled (the handle's own flag clears when it ends)

        def work() -> None:
            self.owner.drop_answers_on_this_thread(lambda: dropped.is_set() or handle.is_cancel_requested)
            try:
                box["reply"] = ask_reply(self.owner.backend, request, steps.put)
            finally:
                self.owner.drop_answers_on_this_thread(None)
                steps.put(None)

        threading.Thread(target=work, name="ravenmem-ask-action", daemon=True).start()
        stage = "planning a path" if request.get("navigate") else "searching memory"
        last = started
        while True:
            try:
                step = steps.get(timeout=POLL_S)
                if step is None:
                    break
            except queue.Empty:
                step = None  # nothing happened: maybe a heartbeat
            if handle.is_cancel_requested:
                return self._cancel(handle, request, dropped)
            now = time.monotonic()
            if step is not None:
                handle.publish_feedback(self._feedback(step, now - started))
                last = now
            elif now - last >= HEARTBEAT_S:
                handle.publish_feedback(self.cls.Feedback(stage=stage, elapsed=now - started))
                last = now
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

    def _feedback(self, step: ToolStep, elapsed: float) -> Any:
        said = f"{step.hits} memories" if step.ok else f"not run: {step.reason}"
        return self.cls.Feedback(
            stage=f"{step.tool}: {said}",
            elapsed=elapsed,
            step=step.step,
            tool=step.tool,
            arguments=step.arguments,
            ok=step.ok,
            hits=step.hits,
        )

    def _cancel(self, handle: Any, request: dict[str, Any], dropped: threading.Event) -> Any:
        navigator = self.owner.navigator
        dropped.set()
        if navigator is not None and request.get("navigate"):
            navigator.cancel()  # the drive this question started stops too
        handle.canceled()
        return fill(self.cls.Result(), {"found": False, "reason": "canceled"})
