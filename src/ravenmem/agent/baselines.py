"""The paper's baselines, answering in the same `Answer` schema as the agent.

- `embedder-only`: the raw question through the text tool, top-1 memory's pose and time.
- `random`: a uniformly random memory (seeded): the floor every method must beat.
- `vlm-only`: the WHOLE history in one prompt, no tools: every memory when they fit, else
  `frames` (the most images the model's context takes) sampled uniformly in time, so its alpha
  is frames / memories and the model's context, not retrieval, decides what it sees. The default
  cap is the release's (1,500 frames; the findingdory preset 3,000, raven-qa-robot-open 20).
"""

from __future__ import annotations

import random
import time
from dataclasses import replace
from typing import TYPE_CHECKING, Any

import numpy as np

from ..errors import InputError
from ..memory.protocol import MemoryLike
from ..timeparse import fmt_time
from ..types import Hit, MemoryRecord
from .loop import Agent, _Run
from .parse import evidence_of
from .questions import classify_question
from .schema import Answer, Cost
from .tool_calls import Shown, describe, record_image

if TYPE_CHECKING:
    from .ask import MethodOptions

DEFAULT_FRAMES = 1500  # the RAVEN release's VLM-only cap (non_agent_max_image_len)


def _record_answer(
    question: str,
    method: str,
    rec: MemoryRecord,
    score: float | None,
    retrieved: int,
    total: int,
    t_start: float,
    embedder: str | None = None,
) -> Answer:
    qtype = classify_question(question)
    p = rec.pose
    ans = Answer(
        question=question,
        method=method,
        embedder=embedder,
        question_type=qtype,
        text=f"Memory m{rec.id}: seen at x={p.x:.2f}, y={p.y:.2f}, z={p.z:.2f} at {fmt_time(rec.t)}.",
        position=[p.x, p.y, p.z],
        yaw=p.yaw,
        position_source="evidence",
        yaw_source="evidence",
        time=rec.t,
        yes=True if qtype == "binary" else None,
        evidence=[evidence_of(Shown(rec, score, None, method))],
    )
    ans.cost = Cost(
        memories_shown=retrieved,
        memories_total=total,
        alpha=retrieved / max(1, total),
        wall_s=round(time.perf_counter() - t_start, 4),
    )
    return ans


class EmbedderOnly:
    """Top-1 of the text (or image) tool for the question as asked: no rewriting, no threshold."""

    name = "embedder-only"

    def __init__(self, memory: MemoryLike, **_: Any) -> None:
        self.memory = memory

    def ask(self, question: str, image: np.ndarray | None = None) -> Answer:
        if not question or not question.strip():
            raise InputError("empty question")
        t_start = time.perf_counter()
        hits: list[Hit] = (
            self.memory.search_image(image, k=1)
            if image is not None
            else self.memory.search_text(question, k=1)
        )
        if not hits:
            return Answer(
                question=question,
                method=self.name,
                question_type=classify_question(question),
                found=False,
                text="The memory returned nothing.",
                embedder=self.memory.embedder.name,
            )
        return _record_answer(
            question,
            self.name,
            hits[0].memory,
            hits[0].score,
            1,
            self.memory.count(),
            t_start,
            self.memory.embedder.name,
        )


class RandomBaseline:
    """A random memory's pose and time (and a coin flip for yes/no), reproducible by seed."""

    name = "random"

    def __init__(self, memory: MemoryLike, seed: int = 0, **_: Any) -> None:
        self.memory = memory
        self.rng = random.Random(seed)
        self._records: list[MemoryRecord] | None = None

    def ask(self, question: str, image: np.ndarray | None = None) -> Answer:
        if not question or not question.strip():
            raise InputError("empty question")
        t_start = time.perf_counter()
        if self._records is None:
            self._records = self.memory.all_records()
        if not self._records:
            raise InputError("the memory is empty")
        rec = self.rng.choice(self._records)
        ans = _record_answer(question, self.name, rec, None, 1, len(self._records), t_start)
        if ans.question_type == "binary":
            ans.yes = self.rng.random() < 0.5
        if ans.question_type == "duration":
            t0, t1 = rec.t, self.rng.choice(self._records).t
            ans.duration = abs(t1 - t0)
        return ans


class VLMOnly(Agent):
    """The whole history in one prompt, no tools: every memory, or `frames` of them evenly
    spaced in time when there are more (set `frames` to what the model's context holds)."""

    name = "vlm-only"
    use_tools = False

    def __init__(self, memory: MemoryLike, options: MethodOptions | None = None, **keywords: Any) -> None:
        from .ask import MethodOptions

        o = (options or MethodOptions.of(self.name, **keywords)).with_preset()
        super().__init__(memory, replace(o, max_tool_calls=0))
        frames = DEFAULT_FRAMES if o.frames is None else o.frames
        if frames < 1:
            raise InputError(f"frames must be >= 1, got {frames}")
        self.frames = frames

    def sample(self) -> list[MemoryRecord]:
        """All memories when at most `frames`, else `frames` evenly spaced in time order."""
        recs = self.memory.all_records()
        if len(recs) <= self.frames:
            return recs
        idx = np.linspace(0, len(recs) - 1, self.frames).round().astype(int)
        return [recs[i] for i in dict.fromkeys(idx.tolist())]

    def _extra_opening(self, run: _Run) -> list[dict[str, Any]]:
        recs = self.sample()
        total = self.memory.count()
        t0 = self.memory.time_span()[0]
        what = "every memory" if len(recs) == total else f"{len(recs)} memories sampled uniformly"
        parts: list[dict[str, Any]] = [
            {"type": "text", "text": f"{what} over the whole recording ({total} in all), in time order:"}
        ]
        for rec in recs:
            run.wm.add(Hit(memory=rec), "history")
            parts.append({"type": "text", "text": describe(rec, t0, scores=self.show_scores)})
            img = record_image(self.memory, rec, self.image_max_side)
            if img is not None:
                parts.append({"type": "image_url", "image_url": {"url": img.url}})
                run.images += 1
                run.image_bytes += img.nbytes
        run.shown_ids.update(run.wm.items)
        run.notes.append(
            f"vlm-only: shown {len(recs)} of {total} memories (at most {self.frames} frames; "
            f"alpha {len(recs) / max(1, total):.3f})"
        )
        return parts
