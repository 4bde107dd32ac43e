"""What a model's reply may hold besides the answer, and the schemas that constrain replies.

Tool calls do not always arrive in `tool_calls`. Servers without a tool parser (vLLM without
`--tool-call-parser`, Qwen and Hermes models, llama.cpp without `--jinja`) leave them in the
text: Hermes-style `<tool_call>{...}</tool_call>` blocks, a JSON object in a markdown fence
with prose around it, a list of calls, `{"name": ..., "parameters": ...}` (Llama 3.x) or our
own JSON-in-prompt form `{"tool": ..., "arguments": ...}`. `text_tool_calls` reads all of them;
an answer object is never mistaken for a call (a call names a tool and carries arguments).

`answer_schema` and `step_schema` are JSON schemas for constrained decoding (`response_format`):
every string and list is bounded, so a grammar-driven small model cannot run on forever.
"""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from typing import Any

from .parse import MAX_REPLY_CHARS, extract_json

MAX_TEXT_CALLS = 8  # tool calls read from one reply's text
MAX_TEXT = 200  # characters of a constrained free-text field
MAX_EVIDENCE = 8
_TOOL_TAG = re.compile(r"<tool_call>\s*(.*?)\s*(?:</tool_call>|$)", re.DOTALL)
_THINK = re.compile(r"<(think|thinking)>.*?(?:</\1>|$)", re.DOTALL | re.IGNORECASE)
QUESTION_TYPES = ["position", "time", "binary", "text", "duration"]


def strip_thinking(text: str | None) -> str:
    """The reply without `<think>...</think>` blocks (Qwen3, DeepSeek-R1 and others through
    Ollama write their thinking into the content): a JSON draft in there is not the answer."""
    return _THINK.sub("", text or "").strip()


def text_tool_calls(text: str | None) -> list[tuple[str, Any]]:
    """Tool calls written in a reply's text, as (name, arguments); [] when there are none."""
    if not text or len(text) > MAX_REPLY_CHARS:
        return []
    if "<tool_call>" in text:
        out: list[tuple[str, Any]] = []
        for block in _TOOL_TAG.findall(text)[:MAX_TEXT_CALLS]:
            obj = extract_json(block)
            calls = json_tool_calls(obj) if obj is not None else []
            out += calls or [("", block[:200])]  # a tag whose body is no call: named by the runner
        return out
    obj = extract_json(text)
    return json_tool_calls(obj) if obj is not None else []


def json_tool_calls(obj: Any) -> list[tuple[str, Any]]:
    """Calls in a decoded JSON value: one call object, a list of them, or {"tool_calls": [...]}."""
    if isinstance(obj, dict) and isinstance(obj.get("tool_calls"), list):
        obj = obj["tool_calls"]
    items: list[Any] = obj if isinstance(obj, list) else [obj]
    out = []
    for it in items[:MAX_TEXT_CALLS]:
        call = _call(it)
        if call is None:
            return []  # not every item is a call: this is an answer (or a list of answers)
        out.append(call)
    return out


def _call(it: Any) -> tuple[str, Any] | None:
    if not isinstance(it, dict):
        return None
    fn: dict[str, Any] = it["function"] if isinstance(it.get("function"), dict) else it
    name = fn.get("tool") or fn.get("name")
    if not isinstance(name, str):
        return None
    for key in ("arguments", "parameters", "args"):
        if key in fn:
            return name, fn[key]
    return (name, {}) if "tool" in fn else None


def answer_schema() -> dict[str, Any]:
    """The answer object (see `prompts.ANSWER_FORMAT`) as a JSON schema. Only what every answer
    has is required (type, text, evidence, found): a grammar then lets a small model stop there
    instead of writing every field (on llama.cpp each constrained token costs a pass over the
    vocabulary, so an answer of 33 tokens instead of 118 is three times faster)."""
    props: dict[str, Any] = {
        "question_type": {"type": "string", "enum": QUESTION_TYPES},
        "answer": {"type": "string", "maxLength": MAX_TEXT},
        "evidence": {"type": "array", "items": {"type": "integer"}, "maxItems": MAX_EVIDENCE},
        "found": {"type": "boolean"},
        "position": {"type": "array", "items": {"type": "number"}, "minItems": 3, "maxItems": 3},
        "yaw_deg": {"type": "number"},
        "time": {"type": "string", "maxLength": 40},
        "duration_s": {"type": "number"},
        "yes": {"type": "boolean"},
        "reasoning": {"type": "string", "maxLength": MAX_TEXT},
    }
    required = ["question_type", "answer", "evidence", "found"]
    return {"type": "object", "properties": props, "required": required, "additionalProperties": False}


def step_schema(
    tool_specs: Sequence[dict[str, Any]], answer: bool = True, required_only: bool = False
) -> dict[str, Any]:
    """One step of the JSON-in-prompt protocol: a call of one of the tools offered, or (unless
    `answer` is False: the model must search first) the answer. `required_only` offers each
    tool's required arguments alone (the forced first search: a small model otherwise fills
    the optional filters with noise, "after": "I am not sure")."""
    calls = []
    for spec in tool_specs:
        fn = spec["function"]
        calls.append(
            {
                "type": "object",
                "properties": {
                    "tool": {"const": fn["name"]},
                    "arguments": _bounded(fn["parameters"], required_only),
                },
                "required": ["tool", "arguments"],
                "additionalProperties": False,
            }
        )
    options = [*calls, answer_schema()] if answer else calls
    return options[0] if len(options) == 1 else {"anyOf": options}


def _bounded(schema: dict[str, Any], required_only: bool = False) -> dict[str, Any]:
    """A copy of an arguments schema with every string given a length limit and every list its
    length (the tools' only list, `near`, is [x, y, radius])."""
    out = json.loads(json.dumps(schema))
    props = out.get("properties", {})
    if required_only:
        out["properties"] = props = {k: v for k, v in props.items() if k in out.get("required", [])}
    for prop in props.values():
        if prop.get("type") == "string":
            prop.setdefault("maxLength", 200)
        elif prop.get("type") == "array":
            prop.setdefault("minItems", 3)
            prop.setdefault("maxItems", 3)
    out["additionalProperties"] = False
    return out


def response_format(kind: str, schema: dict[str, Any], name: str) -> dict[str, Any] | None:
    """The `response_format` field for a schema, in the form the server takes (see VLMConfig)."""
    if kind == "json_schema":
        return {"type": "json_schema", "json_schema": {"name": name, "schema": schema, "strict": False}}
    if kind == "json_object_schema":
        return {"type": "json_object", "schema": schema}
    if kind == "json_object":
        return {"type": "json_object"}
    return None
