"""What providers actually send: reply shapes seen from vLLM, Qwen/Hermes models, Ollama, Gemini's
OpenAI-compatible URL, llama.cpp and broken proxies, as scripts for the scripted server.

Each case is a question, the replies (in order) and what must come of them: `ok` cases must
parse into an answer that passes `check(answer, ids)`; `fail` cases must end as a failed answer
whose error contains `reason` (one named line, never a traceback). `ids` maps the scene's frame
index to its memory id.
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from ravenmem.agent.schema import Answer
from tests.agent.scripted_server import answer, content, tool

WHERE = "Where is the magenta box?"


@dataclass
class Case:
    name: str
    replies: list[dict[str, Any]]
    check: Callable[[Answer, dict[int, int]], bool] | None = None
    reason: str | None = None  # a fail case: the named reason in the answer's error
    question: str = WHERE
    config: dict[str, Any] = field(default_factory=dict)


def _box(ans: Answer, ids: dict[int, int]) -> bool:
    """The magenta box (frame 7) placed by its evidence camera."""
    return not ans.failed and [e.id for e in ans.evidence] == [ids[7]] and ans.position == [7.0, 3.0, 0.5]


def json_text(obj: Any) -> str:
    return json.dumps(obj)


SEARCH = {"name": "search_time", "arguments": {"time": "+70"}}  # shows memories 7, 8, 9
HERMES = f"<tool_call>\n{json_text(SEARCH)}\n</tool_call>"


def box_answer(ids: dict[int, int], **extra: Any) -> dict[str, Any]:
    return answer(question_type="position", answer="By the corner.", evidence=[ids[7]], **extra)


CASES: list[Case] = [
    # ---- tool calls written in the text (servers without a tool parser)
    Case("json call in content", [content(json_text(SEARCH)), "BOX"], _box),
    Case("hermes tags", [content(HERMES), "BOX"], _box),
    Case(
        "hermes tags with prose around",
        [content(f"Let me look.\n{HERMES}\nThen I will answer."), "BOX"],
        _box,
    ),
    Case(
        "two hermes calls in one message",
        [content(HERMES + "\n" + HERMES.replace("+70", "+80")), "BOX"],
        lambda a, ids: _box(a, ids) and a.cost.tool_calls == 2,
    ),
    Case(
        "fenced call with trailing prose",
        [content(f"```json\n{json_text(SEARCH)}\n```\nI'll wait for the results."), "BOX"],
        _box,
    ),
    Case(
        "llama3-style parameters",
        [content(json_text({"name": "search_time", "parameters": {"time": "+70"}})), "BOX"],
        _box,
    ),
    Case("list of calls as JSON", [content(json_text([SEARCH, SEARCH])), "BOX"], _box),
    # ---- native tool calls in other shapes
    Case(
        "several native calls",
        [{"tool_calls": [SEARCH, {"name": "search_text", "arguments": {"query": "magenta"}}]}, "BOX"],
        lambda a, ids: _box(a, ids) and a.cost.tool_calls == 2,
    ),
    Case("arguments as an object", [{"tool_calls": [{**SEARCH, "as_object": True}]}, "BOX"], _box),
    Case(
        "empty tool call ids (gemini)",
        [{"tool_calls": [{**SEARCH, "id": ""}, {**SEARCH, "id": ""}]}, "BOX"],
        _box,
    ),
    Case(
        "unknown tool name is rejected with its name",
        [tool("search_everything", query="box"), tool("search_time", time="+70"), "BOX"],
        lambda a, ids: _box(a, ids) and a.cost.tool_calls_rejected == 1,
    ),
    Case(
        "unknown tool in hermes tags",
        [
            content('<tool_call>{"name": "teleport", "arguments": {}}</tool_call>'),
            tool("search_time", time="+70"),
            "BOX",
        ],
        lambda a, ids: _box(a, ids) and a.cost.tool_calls_rejected == 1,
    ),
    # ---- the answer beside thinking
    Case(
        "reasoning_content beside the answer",
        [tool("search_time", time="+70"), "BOX_REASONING"],
        _box,
    ),
    Case(
        "think tags before the answer",
        [tool("search_time", time="+70"), "BOX_THINK"],
        _box,
    ),
    # ---- numbers as strings, nulls (the RAVEN paper's own answer examples use strings)
    Case(
        "position and yaw as strings",
        [tool("search_time", time="+70"), "BOX_STRINGS"],
        lambda a, ids: (
            not a.failed
            and a.position == [7.1, 3.0, 0.5]
            and a.yaw is not None
            and math.isclose(a.yaw, 3.14 - 2 * math.pi if math.pi < 3.14 else 3.14)
            and a.question_type == "position"
        ),
    ),
    Case(
        "null fields are fields not given",
        [tool("search_time", time="+70"), "BOX_NULLS"],
        _box,
    ),
    Case(
        "binary and question_type read into the answer",
        [tool("search_time", time="+70"), "BINARY"],
        lambda a, ids: not a.failed and a.question_type == "binary" and a.yes is False,
        question="Is there a purple box?",
    ),
    # ---- numbers that are no place, time or span: re-asked, then the question fails by name
    Case("coordinates of 1e308", [tool("search_time", time="+70")] + ["FAR"] * 4, reason="not on a map"),
    Case("NaN coordinates", [tool("search_time", time="+70")] + ["NAN"] * 4, reason="position.0"),
    Case("a duration of 1e308", [tool("search_time", time="+70")] + ["LONG"] * 4, reason="not a span"),
    Case(
        "a time of 1e308 is dropped with a note",
        [tool("search_time", time="+70"), "TIME_FAR"],
        lambda a, ids: (
            not a.failed and a.time is not None and any("not a time of this recording" in n for n in a.notes)
        ),
    ),
    # ---- replies that are not completions
    Case("message null", [{"message": None}] * 4, reason="no JSON object found in the reply (empty)"),
    Case("no choices", [{"choices": []}] * 4, reason="no choices"),
    Case(
        "a 200 with an HTML body",
        [{"raw": "<html><body>Bad gateway</body></html>", "content_type": "text/html"}] * 4,
        reason="body that is not JSON: '<html><body>Bad gateway</body></html>'",
    ),
    Case(
        "an error object with status 200",
        [{"raw": json_text({"error": {"message": "model overloaded"}})}] * 4,
        reason="an error: 'model overloaded'",
    ),
    Case(
        "empty content cut off at max_tokens",
        [{"content": "", "finish_reason": "length"}] * 4,
        reason="cut off (max_tokens reached)",
    ),
]


def materialise(case: Case, ids: dict[int, int]) -> list[dict[str, Any]]:
    """The case's replies with the named answers filled in for this scene's memory ids."""
    named: dict[str, dict[str, Any]] = {
        "BOX": box_answer(ids),
        "BOX_REASONING": {**box_answer(ids), "reasoning_content": "The box is magenta; m7 shows it."},
        "BOX_THINK": content(
            '<think>maybe {"answer": "a draft"}</think>\n'
            + json_text({"question_type": "position", "answer": "By the corner.", "evidence": [ids[7]]})
        ),
        "BOX_STRINGS": content(
            json_text(
                {
                    "question_type": "position",
                    "answer": "By the corner.",
                    "evidence": [str(ids[7])],
                    "position": "[7.1,3.0,0.5]",
                    "yaw": "3.14",
                }
            )
        ),
        "BOX_NULLS": answer(
            question_type="position",
            answer=None,
            evidence=[ids[7]],
            position=None,
            yaw_deg=None,
            time=None,
            duration_s=None,
            yes=None,
            found=None,
            reasoning=None,
        ),
        "BINARY": answer(question_type="yes/no", answer="No.", binary="no", evidence=[ids[7]]),
        "FAR": answer(question_type="position", evidence=[ids[7]], position=[1e308, 0, 0]),
        "NAN": content(f'{{"question_type": "position", "evidence": [{ids[7]}], "position": [NaN, 0, 0]}}'),
        "LONG": answer(question_type="duration", evidence=[ids[7]], duration_s=1e308),
        "TIME_FAR": answer(question_type="time", evidence=[ids[7]], time=1e308),
    }
    return [named[r] if isinstance(r, str) else r for r in case.replies]
