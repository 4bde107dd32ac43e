"""One way to ask: `ask(memory, AskRequest(...)) -> AskResult`, for every front end.

The CLI (`ravenmem ask`), the service (`POST /ask`, MCP `ask`), the evaluation and the robot
links build one `MethodOptions` (method, model, presets, budgets, image settings) and one
`AskRequest`, and call `ask`. It builds the method, answers, and applies the rules every front
end shares: a failed question and an unsupported answer (a position farther than the support
threshold from every memory the model was shown) are refused with one line. Whether such an
answer may be driven to is decided in one place, the goal path (`ravenmem.nav.goals.goal_for`
refuses failed and unsupported answers unless the request allows unsupported ones).

    from ravenmem.agent.ask import AskRequest, MethodOptions, ask
    opts = MethodOptions(method="raven", vlm=VLMConfig(base_url=..., model=...), preset="navqa")
    result = ask(mem, AskRequest("Where is the red mug?", options=opts))
    result.answer, result.refusal, result.exit_code

Navigation planning lives beside this package (`ravenmem.nav`, which the agent does not import),
so a request carries the planner as a function of the answer and of `allow_unsupported`:
`AskRequest(..., plan=lambda ans, allow: goal_for(ans, mem, start, allow_unsupported=allow))`.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any, Literal, Protocol

import numpy as np

from ..errors import InputError, RavenmemError
from ..memory.protocol import MemoryLike
from ..refusal import refusal_of
from .base import METHODS, Method, needs_vlm
from .client import NO_MODEL, VLMClient
from .config import VLMConfig
from .presets import Preset, apply_preset, get_preset
from .schema import Answer

DEFAULT_METHOD = "raven"


@dataclass(frozen=True)
class MethodOptions:
    """How a question is answered; every field left None takes the preset's value, then the
    method's default. `vlm` None means the environment and config file (`VLMConfig.resolve`);
    a `VLMConfig()` without a model means "no model" (a VLM method then fails with one line).

    method: raven | offline | embedder-only | vlm-only | caption | random (or a plugin's name).
    Budgets: `max_tool_calls`, `max_reasks`, `top_k` (N, or {tool: N}). Sampling: `temperature`,
    `seed`. What the model is shown: `show_scores`, `time_mode` (forward | centred | nearest),
    `image_max_side` (px, 0 = as stored), `frames` (vlm-only). `max_position_offset`: metres
    from every memory shown beyond which a model's position is unsupported. The caption
    baseline: `encoder` (its text embedder, None = MiniLM), `captioner`, `auto_caption`,
    `segment_frames`, `segment_s`. `diverse`: whether the text and image tools drop
    near-duplicate hits when the model's call does not say (None: the preset's, False, else
    the tools' own default, True). `offline_config` tunes the offline reasoner; `trace_path`
    keeps the model's requests and replies."""

    method: str = DEFAULT_METHOD
    vlm: VLMConfig | VLMClient | None = None
    preset: str | Preset | None = None
    top_k: int | dict[str, int] | None = None
    max_tool_calls: int | None = None
    max_reasks: int | None = None
    temperature: float | None = None
    seed: int | None = None
    show_scores: bool | None = None
    time_mode: str | None = None
    image_max_side: int | None = None
    max_position_offset: float | None = None
    frames: int | None = None
    diverse: bool | None = None
    segment_frames: int | None = None
    segment_s: float | None = None
    encoder: Any = None
    captioner: VLMConfig | VLMClient | None = None
    auto_caption: bool | None = None
    offline_config: Any = None
    trace_path: str | Path | None = None
    preset_applied: bool = field(default=False, repr=False, compare=False)  # by `with_preset`, once

    @classmethod
    def of(cls, method: str | None = None, **options: Any) -> MethodOptions:
        """Options from keywords, an unknown name a one-line `InputError` naming the known ones."""
        known = {f.name for f in fields(cls)} - {"preset_applied"}
        unknown = sorted(set(options) - known)
        if unknown:
            raise InputError(
                f"unknown method option(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}"
            )
        return cls(method=method or DEFAULT_METHOD, **options)

    @property
    def needs_vlm(self) -> bool:
        return needs_vlm(self.method)

    def check(self) -> MethodOptions:
        """Refuse, in one line and before any work, an unknown method or preset, and a VLM
        method with a config that names no model. Returns self."""
        METHODS.get(self.method)
        get_preset(self.preset)
        vlm = self.vlm
        if self.needs_vlm and isinstance(vlm, VLMConfig) and not vlm.configured:
            raise InputError(f"method {self.method!r} needs a VLM: {NO_MODEL}")
        if self.max_position_offset is not None and not self.max_position_offset >= 0:
            raise InputError(f"max_position_offset must be >= 0 metres, got {self.max_position_offset}")
        return self

    def with_preset(self) -> MethodOptions:
        """The preset's budget, k per tool, temperature, seed, frame cap and `diverse` filled in
        where left None; applied once (the options it returns say so)."""
        if self.preset is None or self.preset_applied:
            return self
        names = ("top_k", "max_tool_calls", "temperature", "seed", "frames", "diverse")
        m = apply_preset(self.preset, {k: getattr(self, k) for k in names}).get
        return replace(
            self,
            top_k=m("top_k"),
            max_tool_calls=m("max_tool_calls"),
            temperature=m("temperature"),
            seed=m("seed"),
            frames=m("frames"),
            diverse=m("diverse"),
            preset_applied=True,
        )


def build_method(memory: MemoryLike, options: MethodOptions) -> Method:
    """The method `options.method` names, built for `memory` from the options it uses."""
    opts = options.check().with_preset()
    name, _, spec = opts.method.partition(":")
    return METHODS.get(name)(spec, memory=memory, options=opts)


def create_method(name: str, memory: MemoryLike, **options: Any) -> Method:
    """`build_method` with the options as keywords: `create_method("raven", mem, preset="navqa")`."""
    return build_method(memory, MethodOptions.of(name, **options))


class PlanLike(Protocol):
    """What `ask` needs of a navigation plan (`ravenmem.nav.goals.GoalPlan` has it)."""

    @property
    def ok(self) -> bool: ...

    def pose_stamped(self, stamp: float | None = None) -> dict[str, Any] | None: ...

    def as_dict(self) -> dict[str, Any]: ...


# what became of a question, typed: every front end's status comes from it (HTTP code, exit
# code, a robot's reason), never from the wording of an error
Outcome = Literal["answered", "out_of_time", "model_failed", "no_answer", "unsupported"]
HTTP_STATUS: dict[str, int] = {
    "answered": 200,
    "out_of_time": 504,
    "model_failed": 502,
    "no_answer": 502,
    "unsupported": 422,
}


@dataclass
class AskRequest:
    """One question: its text, an optional query picture, the method options, and what to do
    with the answer: `plan` ((answer, allow_unsupported) -> plan, the goal path) when the caller
    wants to drive there, and `allow_unsupported` to use (and plan to) an unsupported position."""

    question: str
    options: MethodOptions = field(default_factory=MethodOptions)
    image: np.ndarray | str | Path | None = None
    plan: Callable[[Answer, bool], PlanLike] | None = None
    allow_unsupported: bool = False


@dataclass
class AskResult:
    """The answer, its evidence, the navigation plan (typed, `nav.goals.GoalPlan`; None when
    none was asked for), notes from `ask` itself, and `refusal`: the one line that says why the
    result must not be used (the question failed, or its position is unsupported), None when it
    may. `drive` is what a robot link did with the goal (its NavigateToPose result), when one
    drove there. The answer stays typed until a front end writes its wire format."""

    answer: Answer
    plan: PlanLike | None = None
    notes: list[str] = field(default_factory=list)
    refusal: str | None = None
    drive: dict[str, Any] | None = None

    @property
    def evidence(self) -> list[Any]:
        return list(self.answer.evidence)

    @property
    def navigation(self) -> dict[str, Any] | None:
        """The plan as every front end returns it (`GoalPlan.as_dict`), None without one."""
        return self.plan.as_dict() if self.plan is not None else None

    @property
    def goal(self) -> dict[str, Any] | None:
        """The goal `geometry_msgs/PoseStamped` (JSON) to drive to: only for a result that may
        be used and whose plan found a path."""
        if self.refusal or self.plan is None or not self.plan.ok:
            return None
        return self.plan.pose_stamped()

    @property
    def outcome(self) -> Outcome:
        if self.answer.failed:
            return self.answer.failure or "model_failed"
        return "unsupported" if self.refusal else "answered"

    @property
    def status(self) -> int:
        """The HTTP status of this result, from its `outcome`: 200, 504 (the question ran out of
        time), 502 (the model failed or gave nothing usable), 422 (an unsupported position)."""
        return HTTP_STATUS[self.outcome]

    @property
    def exit_code(self) -> int:
        """0: answered (and, when asked, a path planned); 1: refused, or no path."""
        if self.refusal or (self.plan is not None and not self.plan.ok):
            return 1
        return 0


class QuestionFailed(RavenmemError):
    """A question whose result was refused (see `AskResult.refusal`), with the answer's JSON."""

    def __init__(self, reason: str, answer: dict[str, Any] | None = None, status: int = 502) -> None:
        super().__init__(reason)
        self.answer = answer
        self.status = status


def ask(memory: MemoryLike, request: AskRequest, method: Method | None = None) -> AskResult:
    """Answer `request` from `memory` (with `method` when one is already built, as the
    evaluation reuses one per worker) and apply the refusal rule. With a planner the answer
    always goes to it: the goal path refuses what must not be driven to, with its reason."""
    m = method if method is not None else build_method(memory, request.options)
    ans = m.ask(request.question, image=request.image)  # type: ignore[arg-type]
    # where its position is (REP 105), for every front end and robot link
    ans.frame_id = ans.frame_id or getattr(memory, "frame_id", None)
    ans.map_id = ans.map_id or getattr(memory, "map_id", None)
    result = AskResult(answer=ans, refusal=refusal_of(ans, request.allow_unsupported))
    if ans.unsupported and request.allow_unsupported:
        result.notes.append("unsupported position allowed by the request")
    if request.plan is not None:
        result.plan = request.plan(ans, request.allow_unsupported)
    return result
