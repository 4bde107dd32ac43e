"""What a question is doing while it runs: one typed `ToolStep` per tool call, to a callback.

A model's answer takes seconds and several tool calls; a front end that shows progress (the
ROS 2 question action's feedback, the service's event stream) passes a `Progress` callback
and the agent calls it after each tool call, run or refused, in the order of the answer's
trace. No transport here: the callback decides where a step goes. A callback that raises is
logged and ignored, so showing progress can never fail the question.

    result = service.ask(args, progress=lambda step: print(step.step, step.tool, step.hits))
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any, Protocol, runtime_checkable

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class ToolStep:
    """One tool call of a question, as its trace records it (`Answer.cost` counts the same)."""

    step: int  # 1, 2, ...: this call's place among the question's tool calls (run or refused)
    tool: str  # the tool's name as the model called it (`search_text`, ...)
    arguments: str  # the arguments as the model gave them, JSON, at most 300 characters
    ok: bool  # run (False: refused, see `reason`)
    hits: int  # memories the call returned (0 when it was not run)
    reason: str | None = None  # why it was refused

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


Progress = Callable[[ToolStep], None]


@runtime_checkable
class Reports(Protocol):
    """A method that makes tool calls and reports them (`agent.loop.Agent` and its kin)."""

    progress: Progress | None


def watch(method: object, progress: Progress | None) -> None:
    """Have `method` report its tool calls to `progress` (a method without tool calls has
    nothing to report and is left as it is)."""
    if progress is not None and isinstance(method, Reports):
        method.progress = progress


def report(progress: Progress | None, step: ToolStep) -> None:
    """Hand `step` to `progress`; a failing callback is logged, never raised."""
    if progress is None:
        return
    try:
        progress(step)
    except Exception:
        log.exception("a progress callback failed at tool call %d", step.step)
