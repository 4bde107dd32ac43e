"""The VLM agent: a bounded state machine of model turns, tool runs and answer checks.

    CALL_MODEL --tool calls--> RUN_TOOLS --> CALL_MODEL
    CALL_MODEL --JSON answer--> CHECK_ANSWER --valid--> DONE
    CALL_MODEL / CHECK_ANSWER / RUN_TOOLS --unusable--> REASK --> CALL_MODEL | FAILED

Budgets bound every path: at most `max_tool_calls` tool runs (after that the model is told to
answer and tools are offered with tool_choice "none"), at most `max_reasks` corrective
re-asks, and a hard cap on model turns. Whatever happens, `ask` returns an `Answer`;
transport failures become an explicit failure answer (`failed=True`, `error`).
"""

from __future__ import annotations

import json
import re
import time
from dataclasses import dataclass, field
from enum import Enum
from pathlib import Path
from typing import Any

import numpy as np
from pydantic import ValidationError

from ..errors import InputError
from ..fsio import atomic_write
from ..imageio import read_image
from .base import MemoryLike
from .client import ChatReply, ToolsRejectedError, VLMClient, VLMError, image_data_url
from .config import VLMConfig
from .parse import ModelAnswer, build_answer, evidence_of, extract_json
from .prompts import budget_spent, reask, system_prompt
from .questions import classify_question
from .schema import Answer, Cost
from .tools import ToolRunner, WorkingMemory, image_parts, per_tool_k


class Step(Enum):
    CALL_MODEL = "call_model"
    RUN_TOOLS = "run_tools"
    CHECK_ANSWER = "check_answer"
    REASK = "reask"
    DONE = "done"
    FAILED = "failed"


@dataclass
class _Run:
    """Everything one question accumulates."""

    question: str
    image: np.ndarray | None
    runner: ToolRunner
    mode: str
    messages: list[dict[str, Any]] = field(default_factory=list)
    wm: WorkingMemory = field(default_factory=WorkingMemory)
    shown_ids: set[int] = field(default_factory=set)
    tool_calls: int = 0
    reasks: int = 0
    turns: int = 0
    images: int = 0
    prompt_tokens: int = 0
    completion_tokens: int = 0
    calls: list[tuple[str, str, Any]] = field(default_factory=list)
    candidate: Any = None
    reason: str = ""
    reask_text: str = ""
    answer: Answer | None = None
    error: str | None = None
    notes: list[str] = field(default_factory=list)


class Agent:
    """Answers questions about a memory with a VLM that calls the memory tools.

    `vlm` is a `VLMConfig`, a ready `VLMClient`, or None (settings from the environment and the
    config file). With no VLM configured the agent answers with the offline reasoner and says
    so in `Answer.reasoning` and `Agent.note`.
    """

    name = "raven"
    use_tools = True
    attach_images = True

    def __init__(
        self,
        memory: MemoryLike,
        vlm: VLMConfig | VLMClient | None = None,
        top_k: int | dict[str, int] = 5,
        max_tool_calls: int = 3,
        trace_path: str | Path | None = None,
        max_reasks: int = 2,
        max_position_offset: float = 3.0,
        image_max_side: int = 0,
    ) -> None:
        ks = per_tool_k(top_k)  # one k for every tool, or {"time": 200, "text": 30, ...}
        if max_tool_calls < 0 or max_reasks < 0:
            raise InputError(
                f"need max_tool_calls >= 0, max_reasks >= 0 (got {max_tool_calls}, {max_reasks})"
            )
        self.memory = memory
        self.top_k = top_k
        self.evidence_k = ks["search_text"]
        self.max_tool_calls = max_tool_calls if self.use_tools else 0
        self.max_reasks = max_reasks
        self.max_position_offset = max_position_offset
        self.image_max_side = image_max_side
        self.trace_path = Path(trace_path) if trace_path else None
        self.last_trace: dict[str, Any] | None = None
        self.note = ""
        self.client: VLMClient | None = None
        self.fallback: Any = None
        if isinstance(vlm, VLMClient):
            self.client = vlm
        else:
            cfg = vlm if isinstance(vlm, VLMConfig) else VLMConfig.resolve()
            if cfg.configured:
                self.client = VLMClient(cfg)
        if self.client is None:
            from .offline import OfflineReasoner

            self.fallback = OfflineReasoner(memory, top_k=self.evidence_k)
            self.note = "no VLM configured (set RAVENMEM_VLM_MODEL and RAVENMEM_VLM_BASE_URL): used the offline reasoner"
            self.mode = "offline"
        else:
            self.mode = "json" if self.client.config.tool_mode == "json" else "native"

    # ------------------------------------------------------------------ public
    def ask(self, question: str, image: np.ndarray | str | Path | None = None) -> Answer:
        """Answer one question; never raises for model misbehaviour (see the module docstring)."""
        if not question or not question.strip():
            raise InputError("empty question")
        img = read_image(image) if isinstance(image, (str, Path)) else image
        if self.fallback is not None:
            ans: Answer = self.fallback.ask(question, img)
            ans.reasoning = f"{self.note}. {ans.reasoning}".strip()
            return ans
        assert self.client is not None
        t_start = time.perf_counter()
        first_event = len(self.client.events)
        run = _Run(question=question.strip(), image=img, runner=self._runner(img), mode=self.mode)
        self._open(run)
        try:
            self._loop(run)
        except VLMError as e:
            run.error = str(e)
        answer = run.answer if run.answer is not None else self._failure(run)
        answer.cost = Cost(
            memories_shown=len(run.shown_ids),
            memories_total=self.memory.count(),
            alpha=len(run.shown_ids) / max(1, self.memory.count()),
            images=run.images,
            prompt_tokens=run.prompt_tokens,
            completion_tokens=run.completion_tokens,
            tool_calls=run.tool_calls,
            wall_s=round(time.perf_counter() - t_start, 4),
        )
        self._trace(run, answer, self.client.events[first_event:])
        del self.client.events[first_event:]  # kept in last_trace / the trace file, not forever
        return answer

    # ------------------------------------------------------------------ hooks
    def _runner(self, image: np.ndarray | None) -> ToolRunner:
        return ToolRunner(self.memory, self.top_k, query_image=image, image_max_side=self.image_max_side)

    def _extra_opening(self, run: _Run) -> list[dict[str, Any]]:
        """Content parts added after the question (the vlm-only baseline puts its frames here)."""
        return []

    # ------------------------------------------------------------------ the machine
    def _open(self, run: _Run) -> None:
        tools_on = self.max_tool_calls > 0
        listing = run.runner.prompt_listing() if tools_on and run.mode == "json" else None
        sys_text = system_prompt(
            self.memory.count(),
            self.memory.time_span(),
            listing,
            self.max_tool_calls,
            images=self.attach_images,
        )
        parts: list[dict[str, Any]] = [{"type": "text", "text": f"Question: {run.question}"}]
        if run.image is not None and self.attach_images:
            parts.append({"type": "text", "text": "The user attached this image to the question:"})
            parts.append(
                {"type": "image_url", "image_url": {"url": image_data_url(run.image, self.image_max_side)}}
            )
            run.images += 1
        parts += self._extra_opening(run)
        run.messages = [{"role": "system", "content": sys_text}, {"role": "user", "content": parts}]

    def _loop(self, run: _Run) -> None:
        max_turns = self.max_tool_calls + self.max_reasks + 2
        step = Step.CALL_MODEL
        for _ in range(4 * max_turns + 4):
            if step is Step.CALL_MODEL:
                if run.turns >= max_turns:
                    run.error = f"no usable answer after {run.turns} model turns"
                    return
                step = self._classify(run, self._call(run))
            elif step is Step.RUN_TOOLS:
                step = self._run_tools(run)
            elif step is Step.CHECK_ANSWER:
                step = self._check(run)
            elif step is Step.REASK:
                run.reasks += 1
                if run.reasks > self.max_reasks:
                    run.error = f"no usable answer after {self.max_reasks} re-asks: {run.reason}"
                    return
                run.messages.append({"role": "user", "content": run.reask_text or reask(run.reason)})
                run.reask_text = ""
                step = Step.CALL_MODEL
            else:
                return
        run.error = "the agent loop hit its step limit"

    def _call(self, run: _Run) -> ChatReply:
        assert self.client is not None
        tools = run.runner.specs() if self.max_tool_calls > 0 and run.mode == "native" else None
        choice = "auto" if run.tool_calls < self.max_tool_calls else "none"
        try:
            reply = self.client.chat(run.messages, tools=tools, tool_choice=choice)
        except ToolsRejectedError as e:
            if self.client.config.tool_mode != "auto":
                raise VLMError(f"{e}; set tool_mode to 'json' (--tool-mode json) for this endpoint") from e
            self.mode = run.mode = "json"  # sticky for later questions too
            run.notes.append("endpoint rejected tools: switched to the JSON-in-prompt protocol")
            run.wm, run.tool_calls = WorkingMemory(), 0
            self._open(run)
            reply = self.client.chat(run.messages)
        run.turns += 1
        run.prompt_tokens += reply.prompt_tokens
        run.completion_tokens += reply.completion_tokens
        return reply

    def _classify(self, run: _Run, reply: ChatReply) -> Step:
        if reply.tool_calls:
            run.calls = [(c.id, c.name, c.arguments) for c in reply.tool_calls]
            run.messages.append({
                "role": "assistant",
                "content": reply.content,
                "tool_calls": [
                    {"id": c.id, "type": "function", "function": {"name": c.name, "arguments": c.arguments}}
                    for c in reply.tool_calls
                ],
            })  # fmt: skip
            return Step.RUN_TOOLS
        content = (reply.content or "").strip()
        run.messages.append({"role": "assistant", "content": content or (reply.refusal or "")})
        obj = extract_json(content)
        if obj is None:
            if reply.refusal or reply.finish_reason == "content_filter":
                run.reason = f"the model refused: {(reply.refusal or content)[:200]}"
            elif reply.finish_reason == "length":
                run.reason = "the reply was cut off (max_tokens reached) before the JSON ended"
            else:
                run.reason = "no JSON object found in the reply" + (
                    f" ({content[:80]!r})" if content else " (empty)"
                )
            return Step.REASK
        calls = _json_tool_calls(obj)
        if calls:
            run.calls = [(f"json_call_{run.turns}_{i}", name, args) for i, (name, args) in enumerate(calls)]
            return Step.RUN_TOOLS
        run.candidate = obj
        return Step.CHECK_ANSWER

    def _run_tools(self, run: _Run) -> Step:
        native = run.messages[-1].get("tool_calls") is not None
        if run.tool_calls >= self.max_tool_calls:
            if native:
                for cid, _, _ in run.calls:
                    run.messages.append(
                        {"role": "tool", "tool_call_id": cid, "content": "not run: tool budget spent"}
                    )
            run.reason = "it called tools after the tool budget was spent"
            run.reask_text = budget_spent(self.max_tool_calls)
            return Step.REASK
        texts, images = [], []
        for cid, name, args in run.calls:
            if run.tool_calls < self.max_tool_calls:
                out = run.runner.run(name, args, run.wm)
                run.tool_calls += 1
                images += out.images
                text = out.text
            else:
                text = f"{name}: not run, the tool budget ({self.max_tool_calls} calls) is spent"
            texts.append(text)
            if native:
                run.messages.append({"role": "tool", "tool_call_id": cid, "content": text})
        run.shown_ids.update(run.wm.items)
        run.images += len(images)
        parts: list[dict[str, Any]] = []
        if not native:
            parts.append({"type": "text", "text": "Tool results:\n" + "\n\n".join(texts)})
        if images:
            parts.append({"type": "text", "text": "Images of the memories just retrieved:"})
            parts += image_parts(images, self.client.config.image_detail if self.client else None)
        if run.tool_calls >= self.max_tool_calls:
            parts.append({"type": "text", "text": budget_spent(self.max_tool_calls)})
        if parts:
            run.messages.append({"role": "user", "content": parts})
        return Step.CALL_MODEL

    def _check(self, run: _Run) -> Step:
        obj = run.candidate
        if not isinstance(obj, dict):
            run.reason = "expected one JSON object, got a list"
            return Step.REASK
        try:
            ma = ModelAnswer.model_validate(obj)
        except ValidationError as e:
            errs = "; ".join(
                f"{'.'.join(str(p) for p in err['loc'])}: {err['msg']}" for err in e.errors()[:4]
            )
            run.reason = f"invalid answer fields ({errs})"
            return Step.REASK
        qtype = ma.question_type or classify_question(run.question)
        if qtype == "position" and ma.found and not run.wm.items:
            run.reason = "a 'where' answer must rest on memories, and none were retrieved"
            if self.max_tool_calls > run.tool_calls:
                run.reason += ": search the memory with the tools first"
            return Step.REASK
        ans = build_answer(ma, run.question, run.wm, self.memory, self.name, self.max_position_offset)
        if run.notes:
            ans.reasoning = (ans.reasoning + " [" + "; ".join(run.notes) + "]").strip()
        run.answer = ans
        return Step.DONE

    def _failure(self, run: _Run) -> Answer:
        return Answer(
            question=run.question, method=self.name, question_type=classify_question(run.question),
            text=f"I could not answer: {run.error}", found=False, failed=True, error=run.error,
            evidence=[evidence_of(s) for s in run.wm.ranked()[: self.evidence_k]], reasoning="; ".join(run.notes),
        )  # fmt: skip

    def _trace(self, run: _Run, answer: Answer, events: list[dict[str, Any]]) -> None:
        assert self.client is not None
        trace = {
            "question": run.question,
            "method": self.name,
            "mode": run.mode,
            "vlm": self.client.config.public(),
            "top_k": self.top_k,
            "max_tool_calls": self.max_tool_calls,
            "turns": run.turns,
            "reasks": run.reasks,
            "events": events,
            "answer": answer.model_dump(),
        }
        self.last_trace = trace
        if self.trace_path is None:
            return
        path = self.trace_path
        if path.is_dir() or str(path).endswith(("/", "\\")):
            path.mkdir(parents=True, exist_ok=True)
            slug = re.sub(r"[^a-z0-9]+", "-", run.question.lower()).strip("-")[:40]
            path = path / f"trace_{time.strftime('%Y%m%dT%H%M%S')}_{slug}.json"
        path.parent.mkdir(parents=True, exist_ok=True)
        atomic_write(path, json.dumps(trace, indent=2, default=str))


def _json_tool_calls(obj: Any) -> list[tuple[str, Any]]:
    """Tool requests written as JSON text: {"tool": ..., "arguments": ...}, a list of them, or {"tool_calls": [...]}."""
    if isinstance(obj, dict) and isinstance(obj.get("tool_calls"), list):
        obj = obj["tool_calls"]
    items: list[Any] = obj if isinstance(obj, list) else [obj]
    out = []
    for it in items:
        if not isinstance(it, dict):
            return []
        fn: dict[str, Any] = it["function"] if isinstance(it.get("function"), dict) else it
        name = fn.get("tool") or fn.get("name")
        if not isinstance(name, str) or not ({"arguments", "args", "tool"} & fn.keys()):
            return []
        out.append((name, fn.get("arguments", fn.get("args", {}))))
    return out
