"""An LLM judge for descriptive (text) answers, over the same OpenAI-compatible API as the agent.

Text answers ("what colour was the couch?") have no exact ground truth to compare against, so a
model is shown the question, the reference answer(s) and the candidate and asked for a JSON
verdict. The reply is parsed with pydantic; a reply that is not the JSON asked for falls back to
a leading yes/no, and anything else is recorded as "unparsable" (not scored), never guessed.
"""

from __future__ import annotations

import json
import re
import threading
from typing import Any

from pydantic import BaseModel, ValidationError

from ..agent.client import VLMClient, VLMError
from ..agent.config import VLMConfig
from .recording import RecordingClient

SYSTEM = (
    "You grade answers of a robot that answers questions about what it saw. Decide whether the "
    "candidate answer agrees with the reference answer on the facts the question asks about "
    "(wording, extra detail and politeness do not matter; a contradiction or a missing key fact does). "
    'Reply with JSON only: {"correct": true or false, "reason": "<one short sentence>"}.'
)


class Verdict(BaseModel):
    correct: bool
    reason: str = ""


def parse_verdict(text: str) -> Verdict | None:
    """The judge's JSON verdict (possibly inside a code fence), or a leading yes/no; else None."""
    for cand in re.findall(r"\{.*?\}", text or "", flags=re.S):
        try:
            return Verdict.model_validate(json.loads(cand))
        except (json.JSONDecodeError, ValidationError):
            continue
    w = (text or "").strip().lower()
    if re.match(r"^(yes|correct|true)\b", w):
        return Verdict(correct=True, reason="plain-text verdict")
    if re.match(r"^(no|incorrect|wrong|false)\b", w):
        return Verdict(correct=False, reason="plain-text verdict")
    return None


class Judge:
    """Grades text answers; thread-safe (the runner judges from its worker threads)."""

    def __init__(self, config: VLMConfig, client: VLMClient | None = None) -> None:
        self.config = config
        self.client = client or VLMClient(config)
        self._lock = threading.Lock()

    @property
    def name(self) -> str:
        return str(self.config.model)

    def grade(
        self, question: str, references: list[str], candidate: str, context: str = ""
    ) -> dict[str, Any]:
        """{'correct': bool | None, 'reason': str, 'model': str}; None when the judge's reply is unusable."""
        if not candidate.strip():
            return {"correct": False, "reason": "empty answer", "model": self.name}
        refs = "\n".join(f"- {r}" for r in references) or "- (none given)"
        user = f"Question: {question}\nReference answer(s):\n{refs}\nCandidate answer: {candidate}"
        msgs = [{"role": "system", "content": SYSTEM}, {"role": "user", "content": user}]
        try:
            with self._lock:
                if isinstance(self.client, RecordingClient):
                    self.client.context = context  # the row it judges, in the run's model_io.jsonl
                reply = self.client.chat(msgs)
                self.client.events.clear()
        except VLMError as e:
            return {"correct": None, "reason": f"judge failed: {e}", "model": self.name}
        v = parse_verdict(reply.content or "")
        if v is None:
            return {
                "correct": None,
                "reason": f"unparsable judge reply: {(reply.content or '')[:200]!r}",
                "model": self.name,
            }
        return {
            "correct": v.correct,
            "reason": v.reason,
            "model": self.name,
            "tokens": reply.prompt_tokens + reply.completion_tokens,
        }
