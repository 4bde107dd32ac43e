"""From a model's reply to a validated `Answer`: JSON extraction, lenient typing, evidence rules.

Model output is parsed, never executed: JSON is decoded with `json` (bounded in size and work),
validated by pydantic, and anything else is a malformed reply that the loop re-asks. The model's
position and heading are used as given; the evidence camera's pose fills in only what the model
left out, and every such fallback or correction is recorded in `Answer.notes` with its reason.
"""

from __future__ import annotations

import json
import math
import re
from collections.abc import Iterator
from typing import Annotated, Any

from pydantic import AliasChoices, BaseModel, ConfigDict, Field, field_validator

from ..errors import RavenmemError
from ..memory.protocol import MemoryLike
from ..timeparse import TimeRangeError, parse_duration
from ..types import MemoryRecord
from .questions import classify_question
from .schema import Answer, Evidence, QuestionType
from .tool_calls import Shown, WorkingMemory

MAX_REPLY_CHARS = 200_000  # a JSON answer is a few hundred characters; a longer reply is malformed
MAX_DECODE_ATTEMPTS = 32
MAX_COORD = 1e6  # metres: a map coordinate beyond this is not a place (1e308 would overflow distances)
MAX_DURATION = 1e9  # seconds (~32 years)
TIME_MARGIN = 366 * 86400.0  # a time further than this outside the recording is not one of its times
_FENCE = re.compile(r"```(?:json|JSON)?\s*(.*?)```", re.DOTALL)
_TYPE_SYNONYMS = {
    "location": "position",
    "where": "position",
    "place": "position",
    "pose": "position",
    "when": "time",
    "timestamp": "time",
    "yes/no": "binary",
    "yes_no": "binary",
    "boolean": "binary",
    "bool": "binary",
    "yesno": "binary",
    "how long": "duration",
    "how_long": "duration",
    "description": "text",
    "open": "text",
    "other": "text",
}


def extract_json(text: str | None) -> Any:
    """The first JSON object (or list of objects) in a reply, fenced or not; None when there is none.

    Bounded work: a reply longer than MAX_REPLY_CHARS is not parsed at all, at most
    MAX_DECODE_ATTEMPTS decodes are tried (each linear in the reply), and nesting too deep for
    the decoder is a failed attempt, not a crash.
    """
    if not text or len(text) > MAX_REPLY_CHARS:
        return None
    candidates = [m.group(1).strip() for m in _FENCE.finditer(text)][:MAX_DECODE_ATTEMPTS]
    candidates.append(text.strip())
    dec = json.JSONDecoder()
    attempts = 0
    for cand in candidates:
        for start in _starts(cand):
            attempts += 1
            if attempts > MAX_DECODE_ATTEMPTS:
                return None
            try:
                obj, _ = dec.raw_decode(cand, start)
            except (ValueError, RecursionError):
                continue
            if isinstance(obj, dict) or (isinstance(obj, list) and obj and isinstance(obj[0], dict)):
                return obj
    return None


def _starts(text: str) -> Iterator[int]:
    """Positions where a JSON object or list may begin, in order."""
    i = 0
    while True:
        brace, bracket = text.find("{", i), text.find("[", i)
        found = [p for p in (brace, bracket) if p >= 0]
        if not found:
            return
        i = min(found)
        yield i
        i += 1


Finite = Annotated[float, Field(allow_inf_nan=False)]


class ModelAnswer(BaseModel):
    """The answer object the models are asked for; lenient about spelling, strict about types.

    Numbers may be written as strings (`"3.14"`, `"[1.71,-4.13,0.47]"`, as in the RAVEN paper's
    own examples); `yaw` and `heading` are radians (the schema's unit, and ROS's), `yaw_deg` and
    `heading_deg` degrees; `binary` is read as `yes`; a null field is a field not given. Values
    that are not numbers a place or a time can have (NaN, 1e308) make the answer invalid, so the
    model is asked again."""

    model_config = ConfigDict(extra="ignore")

    question_type: QuestionType | None = None
    answer: str = Field("", validation_alias=AliasChoices("answer", "text"))
    evidence: list[int] = Field(
        default_factory=list,
        validation_alias=AliasChoices("evidence", "evidence_ids", "memory_ids", "memories"),
    )
    position: list[Finite] | None = None
    yaw_deg: Finite | None = Field(None, validation_alias=AliasChoices("yaw_deg", "heading_deg"))
    yaw: Finite | None = Field(None, validation_alias=AliasChoices("yaw", "heading", "yaw_rad"))
    time: float | str | None = None
    duration_s: Finite | None = Field(None, validation_alias=AliasChoices("duration_s", "duration"))
    yes: bool | None = Field(None, validation_alias=AliasChoices("yes", "binary"))
    found: bool = True
    reasoning: str = ""

    @field_validator("answer", "reasoning", mode="before")
    @classmethod
    def _text(cls, v: Any) -> Any:
        if v is None:
            return ""
        return v if isinstance(v, str) else json.dumps(v)

    @field_validator("found", mode="before")
    @classmethod
    def _found(cls, v: Any) -> Any:
        return True if v is None else v

    @field_validator("yaw_deg", "yaw", mode="after")
    @classmethod
    def _angle(cls, v: float | None) -> float | None:
        if v is not None and abs(v) > MAX_COORD:
            raise ValueError(f"a heading of {v:g} is not an angle")
        return v

    @field_validator("yaw", mode="after")
    @classmethod
    def _radians(cls, v: float | None) -> float | None:
        # The listings show headings as `yaw=90deg`, so a model may copy degrees into `yaw`:
        # read as radians, 90 would silently face 117 deg. More than a full turn is not a
        # radian heading; the model is asked again (never guessed to be degrees).
        if v is not None and abs(v) > 2 * math.pi + 1e-6:
            raise ValueError(f"yaw {v:g} is more than a full turn in radians; give degrees as yaw_deg")
        return v

    @field_validator("time", mode="before")
    @classmethod
    def _when(cls, v: Any) -> Any:
        if isinstance(v, bool) or (v is not None and not isinstance(v, (str, int, float))):
            raise ValueError("time must be a number or a string")
        if isinstance(v, (int, float)) and not math.isfinite(v):
            raise ValueError("time must be finite")
        return v

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
        if isinstance(v, str):  # "[1.71,-4.13,0.47]" or "1.71, -4.13, 0.47"
            text = v.strip()
            if text.lower() in ("", "null", "none"):
                return None
            try:
                v = json.loads(text if text.startswith("[") else f"[{text}]")
            except ValueError:
                raise ValueError("position must be [x, y, z] in metres, or null") from None
        if isinstance(v, dict):
            v = [v.get("x"), v.get("y"), v.get("z", 0.0)]
        if v is not None and (not isinstance(v, list) or len(v) not in (2, 3) or any(c is None for c in v)):
            raise ValueError("position must be [x, y, z] in metres, or null")
        return v

    @field_validator("position", mode="after")
    @classmethod
    def _on_map(cls, v: list[float] | None) -> list[float] | None:
        if v is not None and any(abs(c) > MAX_COORD for c in v):
            raise ValueError(f"position {v} is not on a map (coordinates beyond {MAX_COORD:g} m)")
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
                return float(v)
            except ValueError:
                pass
            try:
                return parse_duration(v)
            except RavenmemError as e:
                raise ValueError(str(e)) from e
        return v

    @field_validator("duration_s", mode="after")
    @classmethod
    def _span(cls, v: float | None) -> float | None:
        if v is not None and not 0 <= v <= MAX_DURATION:
            raise ValueError(f"a duration of {v:g} s is not a span of this recording")
        return v


def evidence_of(s: Shown) -> Evidence:
    return Evidence.of(s.record, s.score)


def build_answer(
    ma: ModelAnswer, question: str, wm: WorkingMemory, mem: MemoryLike, method: str, max_offset: float = 3.0
) -> Answer:
    """Apply the evidence rules to a validated model answer; every fallback or correction is
    written to `Answer.notes` with its reason (see docs/agent.md, "Evidence rules")."""
    qtype: QuestionType = ma.question_type or classify_question(question)
    notes: list[str] = []
    ids = list(dict.fromkeys(ma.evidence))
    unknown = [i for i in ids if i not in wm]
    if unknown:
        notes.append(f"dropped evidence ids never shown to the model: {unknown}")
    shown = [wm.items[i] for i in ids if i in wm]
    if not shown and ma.found and wm.items:
        shown = wm.ranked()[:1]
        notes.append(f"no evidence named: used the best-scored memory shown, m{shown[0].record.id}")
    ans = Answer(
        question=question,
        method=method,
        question_type=qtype,
        text=ma.answer.strip(),
        found=ma.found,
        evidence=[evidence_of(s) for s in shown],
        reasoning=ma.reasoning.strip(),
    )
    best = shown[0].record if shown and ma.found else None
    if ma.found:
        _place(ans, ma, best, wm, max_offset, notes)
    elif ma.position is not None or ma.yaw_deg is not None or ma.yaw is not None:
        notes.append("the model's position/heading ignored: its answer says the thing was not found")
    ans.time = _time(ma.time, mem, notes)
    if ans.time is None and best is not None:
        ans.time = best.t
        why = "no time given" if ma.time is None else "the model's time was unreadable"
        notes.append(f"{why}: used the time of evidence memory m{best.id}")
    ans.duration = ma.duration_s
    if qtype == "duration" and ans.duration is None and len(shown) >= 2 and ma.found:
        ts = [s.record.t for s in shown]
        ans.duration = max(ts) - min(ts)
        notes.append("no duration given: used the span of the evidence times")
    ans.yes = ma.yes if ma.yes is not None else (ma.found if qtype == "binary" else None)
    ans.notes = notes
    return ans


def _place(
    ans: Answer,
    ma: ModelAnswer,
    best: MemoryRecord | None,
    wm: WorkingMemory,
    max_offset: float,
    notes: list[str],
) -> None:
    """Position and heading: the model's when given, else the evidence camera's, with notes.

    A model position farther than `max_offset` from every memory shown is kept (the model may
    place a thing it saw down a corridor) but marked `unsupported` with the distance: nothing
    drives there unless the user allows it (docs/agent.md, "Answers that refuse to invent a
    place"). A position with no memory shown at all is unsupported too."""
    if ma.position is not None:
        pos = [float(c) for c in ma.position]
        if len(pos) == 2:
            pos.append(best.pose.z if best else 0.0)
            notes.append(
                f"no height given: used z of evidence memory m{best.id}" if best else "no height given: z = 0"
            )
        ans.position, ans.position_source = pos, "model"
        if wm.items:
            near = min(wm.items.values(), key=lambda s: _dist(pos, s))
            d = _dist(pos, near)
            ans.support_distance = round(d, 3)
            if d > max_offset:
                ans.unsupported = True
                notes.append(
                    f"unsupported: the model's position {_fmt(pos)} is {d:.1f} m from the nearest memory "
                    f"shown (m{near.record.id}), more than {max_offset:g} m"
                )
        else:
            ans.unsupported = True
            notes.append("unsupported: the model gave a position but was shown no memory to rest it on")
    elif best is not None:
        p = best.pose
        ans.position, ans.position_source = [p.x, p.y, p.z], "evidence"
        ans.support_distance = 0.0
        notes.append(f"no position given: used the camera position of evidence memory m{best.id}")
    if ma.yaw is not None:  # radians, as the schema and ROS have it
        ans.yaw, ans.yaw_source = math.remainder(ma.yaw, 2 * math.pi), "model"
    elif ma.yaw_deg is not None:
        ans.yaw, ans.yaw_source = math.radians((ma.yaw_deg + 180.0) % 360.0 - 180.0), "model"
    elif best is not None and ans.position is not None:
        ans.yaw, ans.yaw_source = best.pose.yaw, "evidence"
        notes.append(
            f"no heading given: used the camera heading of evidence memory m{best.id} "
            f"({math.degrees(best.pose.yaw):.0f} deg)"
        )


def _fmt(pos: list[float]) -> str:
    return "[" + ", ".join(f"{c:.2f}" for c in pos) + "]"


def _dist(pos: list[float], s: Shown) -> float:
    p = s.record.pose
    return float(((pos[0] - p.x) ** 2 + (pos[1] - p.y) ** 2 + (pos[2] - p.z) ** 2) ** 0.5)


def _time(value: float | str | None, mem: MemoryLike, notes: list[str]) -> float | None:
    if value is None or (isinstance(value, str) and not value.strip()):
        return None
    try:
        t = float(mem.parse_time(value))
    except TimeRangeError:
        notes.append(f"the model's time {str(value)[:60]!r} is not a time of this recording")
        return None
    except (RavenmemError, ValueError, TypeError, OverflowError) as e:
        notes.append(f"could not read the model's time {str(value)[:60]!r} ({e})")
        return None
    t0, t1 = mem.time_span()
    if not t0 - TIME_MARGIN <= t <= t1 + TIME_MARGIN:
        notes.append(f"the model's time {str(value)[:60]!r} is not a time of this recording")
        return None
    return t
