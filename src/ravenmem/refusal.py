"""The one rule for an answer that must not be used or driven to, on the ground floor so that
both the agent (`agent.ask.ask`: the result's `refusal`) and the goal path (`nav.goals.goal_for`:
no goal) apply the same rule with the same words; only what follows from it differs ("not
used", "the robot stays put").

An answer is refused when its question failed, or when its position is unsupported (farther
than the support threshold from every memory the model was shown) and the request did not allow
unsupported answers. Answers are read by attribute (`agent.schema.Answer` has them all).
"""

from __future__ import annotations

from typing import Any

UNSUPPORTED_NOT_USED = "not used (allow unsupported answers to use it)"


def refusal_of(answer: Any, allow_unsupported: bool = False, then: str | None = None) -> str | None:
    """Why `answer` must not be used, in one line (`then`, what follows from it, after a
    semicolon); None when it may be used."""
    if getattr(answer, "failed", False):
        why = f"the question failed: {getattr(answer, 'error', None) or 'no answer'}"
    elif getattr(answer, "unsupported", False) and not allow_unsupported:
        d = getattr(answer, "support_distance", None)
        where = f"{float(d):.1f} m from every" if isinstance(d, (int, float)) else "not near any"
        why = f"unsupported answer: its position is {where} memory the model was shown"
        then = then or UNSUPPORTED_NOT_USED
    else:
        return None
    return f"{why}; {then}" if then else why
