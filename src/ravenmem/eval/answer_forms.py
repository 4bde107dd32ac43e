"""The forms a multi-goal answer comes in, as the releases' prompts ask for them.

A FindingDory instruction may name several goals ("revisit all the receptacles..."), and each
goal is scored against its own accepted frames, in order. The releases ask models for them in
different ways, and every one is read:

- `frame_indices` field: FindingDory's own prompt asks for JSON {"frame_indices": [12, 40]}, one
  frame index per object or place;
- `Goal times` line: our instructions ask the answer text to end "Goal times: 06:00:43 06:09:36";
- `time` field: the RAVEN release's prompts ask for every goal's time in the answer's "time",
  one string separated by spaces ("06:17:00 06:51:00"), which its scorer splits on spaces;
- frame lists in the text: "[[12, 13], [40]]", FindingDory's answer format written out.

The model's own reply is read for the fields (`reply_fields`: the last reply's JSON, wherever
the answer object sits in it), since the agent's `Answer.time` holds a single instant. The form
that was read is recorded with the prediction (`GoalForm.form`).
"""

from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from typing import Any

MAX_DEPTH = 6  # how deep in a reply's JSON the answer object is looked for
FORMS = ("frame_indices field", "Goal times line", "time field", "frame lists in text")

_LISTS = re.compile(r"\[\s*\[[\d\s,\[\]-]*\]\s*\]")
_GOAL_TIMES = re.compile(r"goal\s+times?\s*[:=]\s*((?:\d{1,2}:\d{2}(?::\d{2}(?:\.\d+)?)?[\s,;]*)+)", re.I)
_HMS = re.compile(r"\b(\d{1,2}):(\d{2})(?::(\d{2}(?:\.\d+)?))?\b")
_CLOCKS_ONLY = re.compile(r"\s*(?:\d{1,2}:\d{2}(?::\d{2}(?:\.\d+)?)?[\s,;]*)+")


def parse_frame_lists(text: str) -> list[list[int]] | None:
    """A FindingDory-style answer '[[12, 13], [40]]' in free text (the last one), else None."""
    found = _LISTS.findall(text or "")
    for cand in reversed(found):
        try:
            val = json.loads(cand)
        except json.JSONDecodeError:
            continue
        if isinstance(val, list) and all(
            isinstance(g, list) and all(isinstance(i, int) for i in g) for g in val
        ):
            return val
    return None


def _seconds(text: str) -> list[float]:
    return [int(h) * 3600 + int(mi) * 60 + float(sec or 0) for h, mi, sec in _HMS.findall(text)]


def parse_goal_times(text: str) -> list[float] | None:
    """The goal times an answer lists ('Goal times: 06:00:43 06:09:36'; H:MM reads as HH:MM:00,
    FindingDory's normalisation) as seconds after midnight, in order; None when it lists none."""
    m = _GOAL_TIMES.search(text or "")
    if not m:
        return None
    return _seconds(m.group(1)) or None


def parse_time_field(value: Any) -> list[float] | None:
    """The RAVEN release's "time" field: clock times separated by spaces (or commas), as seconds
    after midnight; None when the field is not such a string (a number, null, prose)."""
    if not isinstance(value, str) or not _CLOCKS_ONLY.fullmatch(value):
        return None
    return _seconds(value) or None


def _objects(value: Any, depth: int = 0) -> list[dict[str, Any]]:
    """Every JSON object in a decoded reply, outermost first (bounded depth)."""
    if depth > MAX_DEPTH:
        return []
    if isinstance(value, dict):
        out = [value]
        for v in value.values():
            out += _objects(v, depth + 1)
        return out
    if isinstance(value, list):
        return [o for v in value[:32] for o in _objects(v, depth + 1)]
    return []


def reply_fields(texts: list[str]) -> dict[str, Any]:
    """The answer fields a reply's JSON texts (its content and tool-call arguments) carry:
    `time` (as written) and `frame_indices`; {} when none does."""
    from ..agent.parse import extract_json

    out: dict[str, Any] = {}
    for text in texts:
        for obj in _objects(extract_json(text)):
            if "time" in obj and isinstance(obj["time"], str) and "time" not in out:
                out["time"] = obj["time"][:400]
            idx = obj.get("frame_indices")
            if isinstance(idx, list) and "frame_indices" not in out:
                out["frame_indices"] = [i for i in idx[:64] if isinstance(i, int) and not isinstance(i, bool)]
    return out


@dataclass
class GoalForm:
    """Per-goal predicted times (Unix s), whether the answer says nothing answers it, and the
    form they were read from."""

    goals: list[list[float]]
    none: bool
    form: str


def read_goals(text: str, fields: dict[str, Any], frame_times: list[float]) -> GoalForm | None:
    """Every goal's time from the first form the answer uses (order of `FORMS`), mapped onto the
    episode's clock (frame indices through its frames, clock times on its first day); None
    when the answer uses none of them (its single time then stands for the first goal)."""
    if not frame_times:
        return None
    day = math.floor(frame_times[0] / 86400.0) * 86400.0

    def at(i: int) -> float:
        return frame_times[i] if 0 <= i < len(frame_times) else -1.0

    idx = fields.get("frame_indices")
    if isinstance(idx, list) and idx:
        return GoalForm([[at(i)] for i in idx], idx == [-1], FORMS[0])
    listed = parse_goal_times(text)
    if listed is not None:
        return GoalForm([[day + s] for s in listed], False, FORMS[1])
    field = parse_time_field(fields.get("time"))
    if field is not None:
        return GoalForm([[day + s] for s in field], False, FORMS[2])
    lists = parse_frame_lists(text)
    if lists is not None:
        return GoalForm([[at(i) for i in g] for g in lists], lists == [[-1]], FORMS[3])
    return None
