"""The VLM agent: a bounded state machine of model turns, tool runs and answer checks.

    CALL_MODEL --tool calls--> RUN_TOOLS --> CALL_MODEL
    CALL_MODEL --JSON answer--> CHECK_ANSWER --valid--> DONE
    CALL_MODEL / CHECK_ANSWER / RUN_TOOLS --unusable--> REASK --> CALL_MODEL | FAILED

Budgets bound every path: at most `max_tool_calls` tool runs (after that the model is told to
answer and tools are offered with tool_choice "none", or not at all where the server ignores
tool_choice or the answer is constrained by a schema), at most `max_reasks` corrective
re-asks, a hard cap on model turns, and a wall-clock limit per question (the VLM config's
`question_timeout`). Whatever happens, `ask` returns an `Answer`; transport failures and
time-outs become an explicit failure answer (`failed=True`, `error`).

Every tool call, native or written in the text (`agent.replies`), is run or rejected with a
named reason (unknown tool, arguments that are not an object, a failed check), recorded in
the trace. With `response_format` set, requests without tools constrain the reply: the answer
schema, or in the JSON protocol one step (a tool call or the answer). A text-only model
(`vision=False`, or a server that refused pictures once) gets every memory as text.
"""

from __future__ import annotations

import json
import re
import time
from dataclasses import dataclass, field, replace
from enum import Enum
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from pydantic import ValidationError

from ..errors import InputError
from ..fsio import atomic_write
from ..imageio import read_image
from ..memory.protocol import MemoryLike
from .client import (
    NO_MODEL,
    ChatReply,
    ImagesRejectedError,
    OutOfTimeError,
    ToolsRejectedError,
    VLMClient,
    VLMError,
)
from .config import VLMConfig
from .images import data_url, jpeg_of_array
from .labels import FrameLabels
from .parse import MAX_REPLY_CHARS, ModelAnswer, build_answer, evidence_of, extract_json
from .presets import get_preset
from .progress import Progress, ToolStep, report
from .prompts import NO_PICTURES, budget_spent, reask, system_prompt
from .questions import classify_question
from .replies import answer_schema, response_format, step_schema, strip_thinking, text_tool_calls
from .schema import Answer, Cost, Failure
from .tool_calls import (
    DEFAULT_K,
    ToolRunner,
    WorkingMemory,
    attach_changes,
    check_time_mode,
    image_parts,
    per_tool_k,
)

if TYPE_CHECKING:
    from .ask import MethodOptions

DEFAULT_TOOL_CALLS = 3


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
    image_bytes: int = 0
    deadline: float = float("inf")
    prompt_tokens: int = 0
    completion_tokens: int = 0
    calls: list[tuple[str, str, Any]] = field(default_factory=list)
    candidate: Any = None
    reason: str = ""
    reask_text: str = ""
    force_answer: bool = False  # the last reply was prose: ask for the answer object alone, constrained
    force_tool: bool = False  # the last answer rested on no memory: the next step must be a tool call
    answer: Answer | None = None
    error: str | None = None
    failure: Failure = "no_answer"  # the kind of `error`
    notes: list[str] = field(default_factory=list)
    call_log: list[dict[str, Any]] = field(default_factory=list)  # every tool call: ran, or why not


class Agent:
    """Answers questions about a memory with a VLM that calls the four memory tools.

    `vlm` is a `VLMConfig`, a ready `VLMClient`, or None (settings from the environment and the
    config file); without a configured model this raises `InputError` (the model-free reasoner
    is the separate `offline` method). Options left at None come from `preset` (see
    `ravenmem.agent.presets`), then from the built-in defaults (3 tool calls, k=5 per tool):
    `top_k` is one k or {tool: k}; `temperature` and `seed` override the VLM config's;
    `show_scores=False` hides similarity scores and distances from the model; `time_mode`
    "centred" makes the time tool look around the given time instead of forward from it;
    `image_max_side` shrinks the pictures sent (0 = as stored; never enlarged).
    """

    name = "raven"
    use_tools = True
    attach_images = True

    def __init__(self, memory: MemoryLike, options: MethodOptions | None = None, **keywords: Any) -> None:
        """`options` as the method registry builds them (`agent.ask.build_method`), or the same
        fields as keywords (`Agent(mem, vlm=cfg, max_tool_calls=2)`); the preset is applied
        once, by `MethodOptions.with_preset`, and the rest read as they are."""
        from .ask import MethodOptions

        if options is None:
            options = MethodOptions.of(self.name, **keywords)
        elif keywords:
            options = replace(options, **keywords)
        o = options.with_preset()
        vlm = o.vlm
        top_k = DEFAULT_K if o.top_k is None else o.top_k
        max_tool_calls = DEFAULT_TOOL_CALLS if o.max_tool_calls is None else o.max_tool_calls
        max_reasks = 2 if o.max_reasks is None else o.max_reasks
        image_max_side = 0 if o.image_max_side is None else o.image_max_side
        ks = per_tool_k(top_k)  # one k for every tool, or {"time": 200, "text": 30, ...}
        if max_tool_calls < 0 or max_reasks < 0:
            raise InputError(
                f"need max_tool_calls >= 0, max_reasks >= 0 (got {max_tool_calls}, {max_reasks})"
            )
        if image_max_side < 0:
            raise InputError(f"image_max_side must be >= 0 (0 = as stored), got {image_max_side}")
        p = get_preset(o.preset)
        temperature, seed, trace_path = o.temperature, o.seed, o.trace_path
        self.memory = memory
        self.top_k = top_k
        self.ks = ks
        self.evidence_k = ks["search_text"]
        self.max_tool_calls = max_tool_calls if self.use_tools else 0
        self.max_reasks = max_reasks
        self.max_position_offset = 3.0 if o.max_position_offset is None else o.max_position_offset
        self.image_max_side = image_max_side
        self.show_scores = o.show_scores is not False
        self.time_mode = check_time_mode(o.time_mode or "forward")
        self.preset = p.name if p else None
        self.diverse = o.diverse
        self.trace_path = Path(trace_path) if trace_path else None
        self.last_trace: dict[str, Any] | None = None
        if isinstance(vlm, VLMClient):
            self.client = vlm
        else:
            cfg = vlm if isinstance(vlm, VLMConfig) else VLMConfig.resolve()
            if not cfg.configured:
                raise InputError(f"method {self.name!r} needs a VLM: {NO_MODEL}")
            self.client = VLMClient(cfg)
        self.temperature = self.client.config.temperature if temperature is None else float(temperature)
        self.seed = self.client.config.seed if seed is None else int(seed)
        self.mode = "json" if self.client.config.tool_mode == "json" else "native"
        self.text_only = self.client.config.vision is False  # sticky once a server refused pictures
        self.tools_accepted = False  # a request with tools got a reply: later 4xx are not about tools
        self.progress: Progress | None = None  # told of each tool call as it ends (agent.progress)

    # ------------------------------------------------------------------ public
    def ask(self, question: str, image: np.ndarray | str | Path | None = None) -> Answer:
        """Answer one question; never raises for model misbehaviour (see the module docstring)."""
        if not question or not question.strip():
            raise InputError("empty question")
        img = read_image(image) if isinstance(image, (str, Path)) else image
        t_start = time.perf_counter()
        first_event = len(self.client.events)
        run = _Run(question=question.strip(), image=img, runner=self._runner(img), mode=self.mode)
        run.deadline = time.monotonic() + self.client.config.question_timeout
        self._open(run)
        try:
            self._loop(run)
        except VLMError as e:
            run.error = str(e)
            run.failure = "out_of_time" if isinstance(e, OutOfTimeError) else "model_failed"
        answer = run.answer if run.answer is not None else self._failure(run)
        answer.notes = run.notes + answer.notes
        answer.vision = self.attach_images and not self.text_only
        if self.text_only and self.attach_images:
            answer.notes.append(NO_PICTURES)
        answer.model = self.client.config.model
        answer.model_host = self.client.config.host
        answer.embedder = self._embedder_name() if run.runner.embedded else None
        answer.preset = self.preset
        total = self.memory.count()
        answer.cost = Cost(
            memories_shown=len(run.shown_ids),
            memories_total=total,
            alpha=len(run.shown_ids) / max(1, total),
            images=run.images,
            image_bytes=run.image_bytes,
            prompt_tokens=run.prompt_tokens,
            completion_tokens=run.completion_tokens,
            tool_calls=run.tool_calls,
            tool_calls_rejected=sum(1 for c in run.call_log if not c["ok"]),
            wall_s=round(time.perf_counter() - t_start, 4),
        )
        self._trace(run, answer, self.client.events[first_event:])
        del self.client.events[first_event:]  # kept in last_trace / the trace file, not forever
        return answer

    # ------------------------------------------------------------------ hooks
    def _runner(self, image: np.ndarray | None) -> ToolRunner:
        return ToolRunner(
            self.memory,
            self.ks,
            query_image=image,
            image_max_side=self.image_max_side,
            show_scores=self.show_scores,
            time_mode=self.time_mode,
            diverse=self.diverse,
            attach_images=not self.text_only,
            labels=FrameLabels(self.memory) if self.text_only else None,
        )

    def _extra_opening(self, run: _Run) -> list[dict[str, Any]]:
        """Content parts added after the question (the vlm-only baseline puts its frames here)."""
        return []

    def _embedder_name(self) -> str | None:
        """The embedder this method retrieves with, recorded in answers where a text or image
        search ran (read only then: naming it must not load a model that was not needed)."""
        return self.memory.embedder.name

    # ------------------------------------------------------------------ the machine
    def _open(self, run: _Run) -> None:
        tools_on = self.max_tool_calls > 0
        constrained = (self.client.config.response_format or "none") != "none"
        listing = (
            run.runner.prompt_listing(schemas=not constrained) if tools_on and run.mode == "json" else None
        )
        sees = self.attach_images and not self.text_only
        attached = run.image is not None and sees
        sys_text = system_prompt(
            self.memory.count(),
            self.memory.time_span(),
            listing,
            self.max_tool_calls,
            images=sees,
            scores=self.show_scores,
            query_image=run.image is not None and "search_image" in run.runner.names,
            latest=run.runner.latest,
            captions=run.runner.captions is not None,
        )
        parts: list[dict[str, Any]] = [{"type": "text", "text": f"Question: {run.question}"}]
        if run.image is not None and self.attach_images and not sees:
            parts.append(
                {"type": "text", "text": "The user attached an image (you cannot see it; search_image can)."}
            )
        if attached and run.image is not None:
            jpeg = jpeg_of_array(run.image, self.image_max_side)
            parts.append({"type": "text", "text": "The user attached this image to the question:"})
            parts.append({"type": "image_url", "image_url": {"url": data_url(jpeg)}})
            run.images += 1
            run.image_bytes += len(jpeg)
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
                if time.monotonic() >= run.deadline:
                    limit = self.client.config.question_timeout
                    run.error = f"out of time: no usable answer within {limit:g} s (question_timeout)"
                    run.failure = "out_of_time"
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

    def _request(self, run: _Run) -> dict[str, Any]:
        """Tools, tool_choice and response_format of this turn (see the module docstring).

        The model must call a tool (and, with `first_tool`, that tool) on the first turn when
        the config names one, and after an answer that rested on no memory: natively by a
        tool_choice naming the tool, in the JSON protocol by a step schema without the answer."""
        cfg = self.client.config
        budget_left = run.tool_calls < self.max_tool_calls and self.max_tool_calls > 0
        out: dict[str, Any] = {"tools": None, "tool_choice": None, "response_format": None}
        constrain = cfg.response_format or "none"
        if run.force_answer and constrain != "none":
            out["response_format"] = response_format(constrain, answer_schema(), "memory_answer")
            return out
        specs = run.runner.specs() if budget_left else []
        first = cfg.first_tool if run.tool_calls == 0 and cfg.first_tool in run.runner.names else None
        must_search = budget_left and (first is not None or run.force_tool)
        if run.mode == "native" and self.max_tool_calls > 0:
            if budget_left:
                out["tools"] = specs
                out["tool_choice"] = {"type": "function", "function": {"name": first}} if first else "auto"
            elif constrain == "none" and cfg.tool_choice:
                out["tools"], out["tool_choice"] = run.runner.specs(), "none"
        if out["tools"] is None:
            if run.mode == "json" and budget_left:
                named = [sp for sp in specs if sp["function"]["name"] == first] if first else specs
                schema = step_schema(named, answer=not must_search, required_only=first is not None)
                name = "memory_step"
            else:
                schema, name = answer_schema(), "memory_answer"
            out["response_format"] = response_format(constrain, schema, name)
        return out

    def _call(self, run: _Run) -> ChatReply:
        opts: dict[str, Any] = {"temperature": self.temperature, "seed": self.seed, "deadline": run.deadline}
        try:
            try:
                request = self._request(run)
                reply = self.client.chat(run.messages, **request, **opts)
            except ImagesRejectedError as e:
                self._to_text(run, str(e))
                request = self._request(run)
                reply = self.client.chat(run.messages, **request, **opts)
            self.tools_accepted = self.tools_accepted or bool(request["tools"])
        except ToolsRejectedError as e:
            if self.tools_accepted:  # this endpoint took tools before: the refusal is of something else
                raise VLMError(str(e).replace("rejected the tools field", "refused the request")) from e
            if self.client.config.tool_mode != "auto":
                raise VLMError(f"{e}; set tool_mode to 'json' (--tool-mode json) for this endpoint") from e
            self.mode = run.mode = "json"  # sticky for later questions too
            run.notes.append("endpoint rejected tools: switched to the JSON-in-prompt protocol")
            run.wm, run.tool_calls = WorkingMemory(), 0
            self._open(run)
            reply = self.client.chat(run.messages, **self._request(run), **opts)
        run.turns += 1
        run.force_answer = run.force_tool = False
        run.prompt_tokens += reply.prompt_tokens
        run.completion_tokens += reply.completion_tokens
        return reply

    def _to_text(self, run: _Run, why: str) -> None:
        """The server refused pictures: from now on this agent describes memories as text, and
        each picture already in this conversation becomes the labels of what it shows."""
        self.text_only = True
        run.runner.attach_images = False
        run.runner.labels = labels = FrameLabels(self.memory)
        run.notes.append(f"the server refused pictures ({why}): memories are described as text from now on")
        words = labels([s.record for s in run.wm.items.values()]) if run.wm.items else {}
        for msg in run.messages:
            parts = msg.get("content")
            if isinstance(parts, list) and any(p.get("type") == "image_url" for p in parts):
                msg["content"] = _pictures_as_text(parts, words)

    def _classify(self, run: _Run, reply: ChatReply) -> Step:
        if reply.tool_calls:
            run.calls = [
                (c.id or f"call_{run.turns}_{i}", c.name, c.arguments) for i, c in enumerate(reply.tool_calls)
            ]
            run.messages.append(
                {
                    "role": "assistant",
                    "content": reply.content or "",  # not null: chat templates concatenate it
                    "tool_calls": [
                        {
                            "id": cid,
                            "type": "function",
                            "function": {"name": name, "arguments": args},
                        }
                        for cid, name, args in run.calls
                    ],
                }
            )
            return Step.RUN_TOOLS
        content = strip_thinking(reply.content)
        if len(content) > MAX_REPLY_CHARS:
            run.messages.append({"role": "assistant", "content": content[:2000] + " [... cut]"})
            run.reason = f"the reply was {len(content)} characters long; the JSON answer must be short"
            return Step.REASK
        run.messages.append({"role": "assistant", "content": content or (reply.refusal or "")})
        calls = text_tool_calls(content)
        if calls:
            run.calls = [(f"text_call_{run.turns}_{i}", name, args) for i, (name, args) in enumerate(calls)]
            return Step.RUN_TOOLS
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
                run.force_answer = True  # with constraints on, the re-ask gets the answer schema
            return Step.REASK
        run.candidate = obj
        return Step.CHECK_ANSWER

    def _log_call(self, run: _Run, name: str, arguments: str, hits: int, reason: str | None) -> None:
        """One tool call into the trace, and to the progress callback as it ends."""
        shown = arguments[:300]
        run.call_log.append({"name": name, "arguments": shown, "ok": reason is None, "reason": reason})
        report(self.progress, ToolStep(len(run.call_log), name, shown, reason is None, hits, reason))

    def _run_tools(self, run: _Run) -> Step:
        native = run.messages[-1].get("tool_calls") is not None
        if run.tool_calls >= self.max_tool_calls:
            for cid, name, args in run.calls:
                shown = args if isinstance(args, str) else json.dumps(args, default=str)
                self._log_call(run, name, shown, 0, "the tool budget is spent")
                if native:
                    run.messages.append(
                        {"role": "tool", "tool_call_id": cid, "content": "not run: tool budget spent"}
                    )
            run.reason = "it called tools after the tool budget was spent"
            run.reask_text = budget_spent(self.max_tool_calls)
            return Step.REASK
        texts, images = [], []
        for cid, name, args in run.calls:
            hits = 0
            if run.tool_calls < self.max_tool_calls:
                out = run.runner.run(name, args, run.wm)
                run.tool_calls += 1
                images += out.images
                text, hits = out.text, len(out.hits)
                reason = None if out.ok else text.removeprefix("error: ")
            else:
                text = f"{name}: not run, the tool budget ({self.max_tool_calls} calls) is spent"
                reason = "the tool budget is spent"
            shown_args = args if isinstance(args, str) else json.dumps(args, default=str)
            self._log_call(run, name, shown_args, hits, reason)
            texts.append(text)
            if native:
                run.messages.append({"role": "tool", "tool_call_id": cid, "content": text})
        run.shown_ids.update(run.wm.items)
        run.images += len(images)
        run.image_bytes += sum(im.nbytes for im in images)
        parts: list[dict[str, Any]] = []
        if not native:
            parts.append({"type": "text", "text": "Tool results:\n" + "\n\n".join(texts)})
        if images:
            parts.append({"type": "text", "text": "Images of the memories just retrieved:"})
            parts += image_parts(images, self.client.config.image_detail)
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
                run.force_tool = True
            return Step.REASK
        run.answer = build_answer(ma, run.question, run.wm, self.memory, self.name, self.max_position_offset)
        attach_changes(run.answer, run.wm)
        return Step.DONE

    def _failure(self, run: _Run) -> Answer:
        return Answer(
            question=run.question,
            method=self.name,
            question_type=classify_question(run.question),
            text=f"I could not answer: {run.error}",
            found=False,
            failed=True,
            error=run.error,
            failure=run.failure,
            evidence=[evidence_of(s) for s in run.wm.ranked()[: self.evidence_k]],
        )

    def _trace(self, run: _Run, answer: Answer, events: list[dict[str, Any]]) -> None:
        trace = {
            "question": run.question,
            "method": self.name,
            "mode": run.mode,
            "vlm": self.client.config.public(),
            "preset": self.preset,
            "top_k": self.ks,
            "max_tool_calls": self.max_tool_calls,
            "temperature": self.temperature,
            "seed": self.seed,
            "show_scores": self.show_scores,
            "time_mode": self.time_mode,
            "turns": run.turns,
            "reasks": run.reasks,
            "tool_calls": run.call_log,
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


def _pictures_as_text(parts: list[dict[str, Any]], words: dict[int, list[str]]) -> list[dict[str, Any]]:
    """Content parts with each picture replaced by the labels of the memory it shows (named by
    the `[m12] at ...` text part before it), or a line saying it is not shown."""
    out: list[dict[str, Any]] = []
    for part in parts:
        if part.get("type") != "image_url":
            out.append(part)
            continue
        prev = out[-1].get("text", "") if out else ""
        found = re.match(r"\[m(\d+)\]", prev)
        labels = words.get(int(found.group(1))) if found else None
        text = (
            f"picture shows (labels): {', '.join(labels)}"
            if labels
            else "(picture not shown: text-only model)"
        )
        out.append({"type": "text", "text": text})
    return out
