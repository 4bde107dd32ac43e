"""The common shape every benchmark loader produces: episodes of frames plus scored questions.

One structure for NaVQA, FindingDory, RAVEN-QA and our own `questions.json`, so that the runner,
the metrics and the reports never look at a dataset's native format. Ground truth is kept in
plain numbers (metres, Unix seconds, frame indices) and travels with every answer row, so a run
folder can be re-scored later without the dataset.
"""

from __future__ import annotations

import bisect
from collections.abc import Callable, Iterable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Literal

from ..types import Frame

EvalType = Literal["position", "time", "binary", "text", "duration", "frame"]
EVAL_TYPES: tuple[str, ...] = ("position", "time", "binary", "text", "duration", "frame")
HORIZONS = ("short", "medium", "long")


@dataclass
class Truth:
    """Ground truth of one question; a question is scored against the fields its type uses.

    positions: accepted [x, y, z] (any one is right). times: accepted instants (Unix s).
    window: an accepted time interval (Unix s). frames: per goal, the accepted frame indices
    (FindingDory style; `[[-1]]` means "no such frame"). files: accepted frame file names.
    Relative times (`rel_times`, `rel_window`, seconds from the episode's first frame) are
    turned into absolute ones by `resolve` once the episode's start is known.
    """

    positions: list[list[float]] = field(default_factory=list)
    times: list[float] = field(default_factory=list)
    window: list[float] | None = None
    frames: list[list[int]] = field(default_factory=list)
    files: list[str] = field(default_factory=list)
    text: list[str] = field(default_factory=list)
    yes: bool | None = None
    duration: float | None = None  # seconds
    none: bool = False  # the right answer is "never seen"
    pos_tol: float | None = None  # metres; overrides the run's threshold for this question
    time_tol: float | None = None  # seconds; overrides the run's threshold for this question
    rel_times: list[float] = field(default_factory=list)
    rel_window: list[float] | None = None

    def resolve(self, t0: float) -> None:
        """Turn times given relative to the episode start into Unix seconds (idempotent)."""
        if self.rel_times:
            self.times = sorted(set(self.times) | {t0 + r for r in self.rel_times})
            self.rel_times = []
        if self.rel_window is not None:
            self.window = [t0 + self.rel_window[0], t0 + self.rel_window[1]]
            self.rel_window = None

    def to_dict(self) -> dict[str, Any]:
        """Every field that holds a value: a "no" (`yes=False`), a 0 s duration and 0 m tolerances
        included; only unset (None) fields and empty lists are left out."""
        return {
            k: v for k, v in asdict(self).items() if v is not None and not (isinstance(v, list) and not v)
        }

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> Truth:
        return cls(**{k: v for k, v in d.items() if k in cls.__dataclass_fields__})


@dataclass
class Question:
    """One question of an episode: text, how it is scored, and how it is broken down."""

    id: str
    text: str
    type: EvalType
    truth: Truth
    category: str = ""
    horizon: str = ""  # short / medium / long; filled from the episode length when empty
    image: Path | None = None  # query image ("where did I see this?")
    subset: str = ""  # RAVEN-QA: the recording's source (web, self-recorded, sim, real_world, ...)
    split: str = ""  # RAVEN-QA: simple / hard
    # how to answer, for the methods that ask a model (e.g. FindingDory: every goal's time); the
    # retrieval baselines search the question itself
    instructions: str = ""
    meta: dict[str, Any] = field(default_factory=dict)

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {
            "id": self.id,
            "text": self.text,
            "type": self.type,
            "category": self.category,
            "horizon": self.horizon,
            "subset": self.subset,
            "split": self.split,
            "image": str(self.image) if self.image else None,
        }
        if self.instructions:
            d["instructions"] = self.instructions
        if self.meta:
            d["meta"] = self.meta
        return d


@dataclass
class Episode:
    """A recording and the questions asked about it.

    `frames` is a zero-argument factory returning a fresh iterable of `Frame`s (a FrameSource),
    so the same episode can be ingested again with other keyframe settings. `key` names the
    episode's content for the memory cache (dataset path + episode + time window). `frame_times`
    (chronological, Unix s) and `frame_files` (same order) map answers back to frames when the
    loader knows them without decoding images.
    """

    id: str
    dataset: str
    key: str
    frames: Callable[[], Iterable[Frame]]
    questions: list[Question]
    frame_times: list[float] = field(default_factory=list)
    frame_files: list[str] = field(default_factory=list)
    trajectory: list[tuple[float, float, float]] = field(default_factory=list)  # (t, x, y) for coverage
    has_poses: bool = True
    pos_threshold: float | None = None  # the dataset's default position threshold for this episode
    frame_tol: float | None = None  # seconds either side of an accepted frame that still count
    t0: float | None = None  # first frame time, for truths given relative to the start
    memory_path: Path | None = None  # an existing memory to query instead of ingesting `frames`
    meta: dict[str, Any] = field(default_factory=dict)

    @property
    def duration(self) -> float | None:
        return (self.frame_times[-1] - self.frame_times[0]) if len(self.frame_times) > 1 else None

    def nearest_frame(self, t: float) -> int | None:
        """Index of the frame closest in time to t (None when the loader gave no frame times)."""
        ft = self.frame_times
        if not ft:
            return None
        i = bisect.bisect_left(ft, t)
        if i == 0:
            return 0
        if i >= len(ft):
            return len(ft) - 1
        return i if ft[i] - t < t - ft[i - 1] else i - 1


def horizon_of(duration_s: float | None) -> str:
    """NaVQA's length classes: short < 2 min <= medium <= 7 min < long."""
    if duration_s is None:
        return ""
    if duration_s < 120:
        return "short"
    return "medium" if duration_s <= 420 else "long"
