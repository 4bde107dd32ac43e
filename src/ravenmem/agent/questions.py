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
    if (
        re.match(r"^(when|what time|at what time|since when|until when)\b", s)
        or re.search(r"\bwhat time\b", s)
        or _ORDER_TIME.match(s)
    ):
        return "time"
    if re.match(r"^(where|which (place|room|location|spot|way))\b", s) or re.search(r"\bwhere\b", s):
        return "position"
    if _BINARY_START.match(s):
        return "binary"
    if re.search(r"\bwhen\b", s):
        return "time"
    return "text"


# "what was the last time I saw ...": a time question, though it starts with "what"
_ORDER_TIME = re.compile(
    r"^(?:what|which) (?:was|is|were) the (?:very )?(?:last|latest|first|earliest|most recent) time\b"
)
_LAST = re.compile(r"\b(last|latest|most recent(ly)?|recently|lately|again)\b", re.IGNORECASE)
_FIRST = re.compile(r"\b(first(?! aid)|earliest|initially|originally)\b", re.IGNORECASE)
# The words that say which sighting is meant, wherever they stand in the question: "the last time
# I saw it", "for the first time", "most recently", "last". They are not part of the thing asked
# about, so subject_phrase drops them before it cuts out the subject.
_ORDER_WORDS = re.compile(
    r"\s*(?:\b(?:for|at) )?\bthe (?:very )?(?:last|latest|first|earliest|most recent) time"
    r"(?: (?:that )?(?:i|we|you|it|they|the robot) (?:saw|seen|see|noticed|spotted|passed|visited)"
    r"(?: (?:it|them|one))?)?\b"
    r"|\s*\b(?:most |least )?recently\b|\s*\blately\b"
    r"|\s*\b(?:last|latest|first(?! aid)|earliest|initially|originally)\b",
    re.IGNORECASE,
)
# "the keyboard I saw", "the keyboard seen": the seeing is the question's, not the thing's
_SEEN_TAIL = re.compile(
    r"\s+(?:(?:that |which )?(?:i|we|you|it|they|the robot) )?(?:saw|seen|spotted|noticed)(?: (?:it|them))?$",
    re.IGNORECASE,
)


def temporal_order(question: str) -> Order:
    """Which occurrence the question is about: the last, the first, or simply the best match."""
    if _LAST.search(question):
        return "last"
    if _FIRST.search(question):
        return "first"
    return "best"


_LEADS = [
    r"where (?:was|were) (?:i|we|the robot) when (?:i|we|it|they|the robot) (?:saw|passed|found|noticed|spotted)\b",
    r"where (?:did|do|have|had|was|were|is|are|can|could|would|should) (?:i|we|you|it|they|the robot)?\s*(?:last |first |ever )?"
    r"(?:leave|left|put|place|placed|see|saw|seen|find|found|notice|noticed|pass|passed|park|parked|drop|dropped|go|get|store|stored|keep|kept|spot|spotted)?\b",
    r"where (?:is|are|was|were) (?:there )?",
    r"where",
    r"when (?:did|do|have|had|was|were|is|are) (?:i|we|you|it|they|the robot)?\s*(?:last |first |ever )?"
    r"(?:see|saw|seen|pass|passed|visit|visited|go (?:by|past|to)|went (?:by|past|to)|walk (?:by|past)|notice|noticed|use|used|leave|left|find|found|enter|entered|get to|reach|reached|spot|spotted)?\b",
    r"when",
    r"(?:at )?what time (?:did|do|was|were) (?:i|we|you|it|they|the robot)?\s*(?:last |first )?(?:see|saw|pass|passed|visit|visited|leave|left)?\b",
    r"how long (?:did|do|was|were|have|had) (?:i|we|you|it|they|the robot)?\s*(?:spend|spent|stay|stayed|stand|stood|look at|looked at|be|been|see|saw|watch|watched)?\b\s*(?:in|at|near|by|with)?\b",
    r"how long",
    r"(?:is|are|was|were) there (?:any |a |an |some )?",
    r"(?:did|do|have|has|had) (?:i|we|you|it|they|the robot) (?:ever )?(?:see|saw|seen|pass|passed|visit|visited|find|found|notice|noticed)?\b",
    r"(?:can|could) (?:i|we|you) (?:see|find)?\b",
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
    """The thing asked about: 'Where did I leave the red backpack?' -> 'red backpack', and in every
    phrasing of "last" / "first": 'Where was the keyboard last seen?', 'When was the last time I
    saw the keyboard?' and 'Where did I see the keyboard most recently?' -> 'keyboard'."""
    s = " ".join(question.strip().split())
    s = " ".join(_ORDER_WORDS.sub("", s).split())
    s = _LEAD.sub("", s, count=1)
    s = _TRAIL.sub("", s)
    s = _ARTICLE.sub("", s)
    s = s.strip(" ?.!,")
    s = _SEEN_TAIL.sub("", s)
    return s or question.strip(" ?.!")


def fmt_duration(seconds: float) -> str:
    s = abs(seconds)
    if s < 120:
        return f"{seconds:.1f} s"
    if s < 7200:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.2f} h"
