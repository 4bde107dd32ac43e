"""What kind of question is this, and which words carry it: rules, no model.

Used by every method: the VLM agent falls back on it when the model names no question type,
and the offline reasoner builds its whole answer from it.
"""

from __future__ import annotations

import re
from typing import Literal

from .schema import QuestionType

Order = Literal["last", "first", "best"]

_BINARY_START = re.compile(
    r"^(is|are|was|were|did|do|does|have|has|had|can|could|will|would|should|am)\b", re.IGNORECASE
)


def classify_question(question: str) -> QuestionType:
    """position | time | binary | text | duration from the question's wording."""
    s = " ".join(question.lower().split())
    if re.search(r"\bhow long\b|\bhow many (seconds|minutes|hours)\b|\bfor how much time\b|\bduration\b", s):
        return "duration"
    if re.match(r"^(when|what time|at what time|since when|until when)\b", s) or re.search(
        r"\bwhat time\b", s
    ):
        return "time"
    if re.match(r"^(where|which (place|room|location|spot|way))\b", s) or re.search(r"\bwhere\b", s):
        return "position"
    if _BINARY_START.match(s):
        return "binary"
    if re.search(r"\bwhen\b", s):
        return "time"
    return "text"


def temporal_order(question: str) -> Order:
    """Which occurrence the question is about: the last, the first, or simply the best match."""
    s = question.lower()
    if re.search(r"\b(last|latest|most recent(ly)?|recently|lately|again)\b", s):
        return "last"
    if re.search(r"\b(first|earliest|initially|originally)\b", s):
        return "first"
    return "best"


_LEADS = [
    r"where (?:did|do|have|had|was|were|is|are|can|could|would|should) (?:i|we|you|it|they|the robot)?\s*(?:last |first |ever )?"
    r"(?:leave|left|put|place|placed|see|saw|seen|find|found|notice|noticed|pass|passed|park|parked|drop|dropped|go|get|store|stored|keep|kept|spot|spotted)?",
    r"where (?:is|are|was|were) (?:there )?",
    r"where",
    r"when (?:did|do|have|had|was|were|is|are) (?:i|we|you|it|they|the robot)?\s*(?:last |first |ever )?"
    r"(?:see|saw|seen|pass|passed|visit|visited|go (?:by|past|to)|went (?:by|past|to)|walk (?:by|past)|notice|noticed|use|used|leave|left|find|found|enter|entered|get to|reach|reached|spot|spotted)?",
    r"when",
    r"(?:at )?what time (?:did|do|was|were) (?:i|we|you|it|they|the robot)?\s*(?:last |first )?(?:see|saw|pass|passed|visit|visited|leave|left)?",
    r"how long (?:did|do|was|were|have|had) (?:i|we|you|it|they|the robot)?\s*(?:spend|spent|stay|stayed|stand|stood|look at|looked at|be|been|see|saw|watch|watched)?\s*(?:in|at|near|by|with)?",
    r"how long",
    r"(?:is|are|was|were) there (?:any |a |an |some )?",
    r"(?:did|do|have|has|had) (?:i|we|you|it|they|the robot) (?:ever )?(?:see|saw|seen|pass|passed|visit|visited|find|found|notice|noticed)?",
    r"(?:can|could) (?:i|we|you) (?:see|find)?",
    r"what (?:is|was|are|were) (?:written|shown|displayed) on",
    r"what (?:colou?r|kind|brand|number|name) (?:is|was|are|were)",
    r"what (?:is|was|are|were)",
    r"which",
]
_LEAD = re.compile(r"^(?:" + "|".join(f"(?:{p})" for p in _LEADS) + r")\s*", re.IGNORECASE)
_TRAIL = re.compile(
    r"\s*(?:\b(?:last|first|today|yesterday|recently|earlier|before|again|ever|at|on|in|by|the last time|"
    r"last time|this morning|this afternoon)\b\s*)*[?.!]*$",
    re.IGNORECASE,
)
_ARTICLE = re.compile(r"^(?:the|a|an|my|our|your|some|any|that|this)\s+", re.IGNORECASE)


def subject_phrase(question: str) -> str:
    """The thing asked about: 'Where did I leave the red backpack?' -> 'red backpack'."""
    s = " ".join(question.strip().split())
    s = _LEAD.sub("", s, count=1)
    s = _TRAIL.sub("", s)
    s = _ARTICLE.sub("", s)
    s = s.strip(" ?.!,")
    return s or question.strip(" ?.!")


def fmt_duration(seconds: float) -> str:
    s = abs(seconds)
    if s < 120:
        return f"{seconds:.1f} s"
    if s < 7200:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.2f} h"
