"""From a model's reply to a validated `Answer`: JSON extraction, lenient typing, evidence rules.

Model output is parsed, never executed: JSON is decoded with `json`, validated by pydantic, and
anything else is a malformed reply that the loop re-asks. Coordinates are taken from evidence
memories; a model's own coordinates are kept only when they lie near something it was shown,
and the heading (yaw) always comes from the best evidence memory.
"""

from __future__ import annotations

import json
import re
from typing import Any

from pydantic import AliasChoices, BaseModel, ConfigDict, Field, field_validator

from ..errors import RavenmemError
from ..timeparse import parse_duration
from .base import MemoryLike
from .questions import classify_question
from .schema import Answer, Evidence, QuestionType
from .tools import Shown, WorkingMemory

_FENCE = re.compile(r"```(?:json|JSON)?\s*(.*?)```", re.DOTALL)
_TYPE_SYNONYMS = {
    "location": "position", "where": "position", "place": "position", "pose": "position",
    "when": "time", "timestamp": "time", "yes/no": "binary", "yes_no": "binary", "boolean": "binary",
    "bool": "binary", "yesno": "binary", "how long": "duration", "how_long": "duration",
    "description": "text", "open": "text", "other": "text",
}  # fmt: skip


def extract_json(text: str | None) -> Any:
    """The first JSON object (or array) in a reply, fenced or not; None when there is none."""
    if not text:
        return None
    candidates = [m.group(1) for m in _FENCE.finditer(text)] + [text]
    dec = json.JSONDecoder()
    for cand in candidates:
        cand = cand.strip()
        try:
            return json.loads(cand)
        except json.JSONDecodeError:
            pass
        for i, ch in enumerate(cand):
            if ch in "{[":
                try:
                    obj, _ = dec.raw_decode(cand, i)
                except json.JSONDecodeError:
                    continue
                if isinstance(obj, dict) or (isinstance(obj, list) and obj and isinstance(obj[0], dict)):
                    return obj
    return None


class ModelAnswer(BaseModel):
    """The answer object the models are asked for; lenient about spelling, strict about types."""

    model_config = ConfigDict(extra="ignore")

    question_type: QuestionType | None = None
    answer: str = Field("", validation_alias=AliasChoices("answer", "text"))
    evidence: list[int] = Field(
        default_factory=list,
        validation_alias=AliasChoices("evidence", "evidence_ids", "memory_ids", "memories"),
    )
    position: list[float] | None = None
    time: float | str | None = None
    duration_s: float | None = Field(None, validation_alias=AliasChoices("duration_s", "duration"))
    yes: bool | None = None
    found: bool = True
    reasoning: str = ""

    @field_validator("question_type", mode="before")
    @classmethod
    def _qtype(cls, v: Any) -> Any:
        if isinstance(v, str):
            v = v.strip().lower()
            return _TYPE_SYNONYMS.get(v, v) or None
        return v

    @field_validator("evidence", mode="before")
    @classmethod
    def _ids(cls, v: Any) -> Any:
        if v is None:
            return []
        if not isinstance(v, list):
            v = [v]
        out = []
        for item in v:
            if isinstance(item, dict):
                item = item.get("id", item.get("memory_id"))
            if isinstance(item, str):
                m = re.fullmatch(r"\s*\[?m?(\d+)\]?\s*", item, re.IGNORECASE)
                if not m:
                    raise ValueError(f"evidence id {item!r} is not a memory id like 12 or 'm12'")
                item = int(m.group(1))
            out.append(item)
        return out

    @field_validator("position", mode="before")
    @classmethod
    def _pos(cls, v: Any) -> Any:
        if isinstance(v, dict):
            v = [v.get("x"), v.get("y"), v.get("z", 0.0)]
        if v is not None and (not isinstance(v, list) or len(v) not in (2, 3) or any(c is None for c in v)):
            raise ValueError("position must be [x, y, z] in metres, or null")
        return v

    @field_validator("yes", "found", mode="before")
    @classmethod
    def _bool(cls, v: Any) -> Any:
        if isinstance(v, str) and v.strip().lower() in ("yes", "true", "y"):
            return True
        if isinstance(v, str) and v.strip().lower() in ("no", "false", "n"):
            return False
        return v

    @field_validator("duration_s", mode="before")
    @classmethod
    def _dur(cls, v: Any) -> Any:
        if isinstance(v, str):
            try:
                return parse_duration(v)
            except RavenmemError as e:
                raise ValueError(str(e)) from e
        return v


def evidence_of(s: Shown) -> Evidence:
    p = s.record.pose
    return Evidence(
        id=s.record.id,
        t=s.record.t,
        x=p.x,
        y=p.y,
        z=p.z,
        yaw=p.yaw,
        score=s.score,
        image_path=s.record.image_path,
    )


def build_answer(
    ma: ModelAnswer, question: str, wm: WorkingMemory, mem: MemoryLike, method: str, max_offset: float = 3.0
) -> Answer:
    """Apply the evidence rules to a validated model answer (see the module docstring)."""
    qtype: QuestionType = ma.question_type or classify_question(question)
    notes: list[str] = []
    ids = list(dict.fromkeys(ma.evidence))
    unknown = [i for i in ids if i not in wm]
    if unknown:
        notes.append(f"dropped evidence ids never shown: {unknown}")
    shown = [wm.items[i] for i in ids if i in wm]
    if not shown and ma.found and wm.items:
        shown = wm.ranked()[:1]
        notes.append(f"no evidence named; using the best retrieved memory m{shown[0].record.id}")
    ans = Answer(
        question=question, method=method, question_type=qtype, text=ma.answer.strip(), found=ma.found,
        evidence=[evidence_of(s) for s in shown], reasoning=ma.reasoning.strip(), yaw=None,
    )  # fmt: skip
    best = shown[0].record if shown and ma.found else None
    if ma.found and ma.position is not None:
        pos = [float(c) for c in ma.position] + (
            [best.pose.z if best else 0.0] if len(ma.position) == 2 else []
        )
        near = [s for s in wm.items.values() if _dist(pos, s) <= max_offset]
        if near:
            ans.position, ans.position_source = pos, "model"
            ans.yaw = best.pose.yaw if best else None
        else:
            notes.append(f"model position {pos} is over {max_offset:g} m from every memory shown; replaced")
    if best is not None and ans.position is None:
        ans.position, ans.yaw, ans.position_source = (
            [best.pose.x, best.pose.y, best.pose.z],
            best.pose.yaw,
            "evidence",
        )
    ans.time = _time(ma.time, mem, notes)
    if ans.time is None and best is not None:
        ans.time = best.t
    ans.duration = ma.duration_s
    if qtype == "duration" and ans.duration is None and len(shown) >= 2 and ma.found:
        ts = [s.record.t for s in shown]
        ans.duration = max(ts) - min(ts)
        notes.append("duration taken from the span of the evidence times")
    ans.yes = ma.yes if ma.yes is not None else (ma.found if qtype == "binary" else None)
    if notes:
        ans.reasoning = (ans.reasoning + " [" + "; ".join(notes) + "]").strip()
    return ans


def _dist(pos: list[float], s: Shown) -> float:
    p = s.record.pose
    return float(((pos[0] - p.x) ** 2 + (pos[1] - p.y) ** 2 + (pos[2] - p.z) ** 2) ** 0.5)


def _time(value: float | str | None, mem: MemoryLike, notes: list[str]) -> float | None:
    if value is None or (isinstance(value, str) and not value.strip()):
        return None
    try:
        return float(mem.parse_time(value))
    except (RavenmemError, ValueError, TypeError) as e:
        notes.append(f"could not read the model's time {value!r} ({e})")
        return None
