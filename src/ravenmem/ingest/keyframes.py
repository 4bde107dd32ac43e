"""Keyframe selection: keep few, informative frames before paying for embeddings.

Two stages. `select_frames` is cheap and runs before the embedder: a stride, a target rate from
timestamps, and pose-motion novelty (keep when the camera moved or turned enough since the last
kept frame). `NoveltyFilter` runs after the embedder: drop a frame whose embedding is too similar
(cosine) to the last kept one, so a robot parked in front of a wall stores one memory, not 1000.
Each stage counts what it dropped and why.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, fields, replace

import numpy as np

from ..errors import InputError
from ..types import Frame, Pose

DROP_STRIDE = "stride"
DROP_FPS = "above target fps"
DROP_MOTION = "too little motion"
DROP_SIMILAR = "similar to last keyframe"


@dataclass
class KeyframeConfig:
    """Selection rules; None disables a rule. With nothing set every frame is kept.

    stride: keep every n-th incoming frame. fps: at most this many frames per second of source
    time. min_translation (m) / min_rotation (rad): keep a frame when it moved at least this far
    OR turned at least this much since the last kept frame (the first frame is always kept).
    max_similarity: after embedding, drop a frame whose cosine similarity to the last kept
    frame's embedding is above this.
    """

    stride: int = 1
    fps: float | None = None
    min_translation: float | None = None
    min_rotation: float | None = None
    max_similarity: float | None = None

    def __post_init__(self) -> None:
        if isinstance(self.stride, bool) or not isinstance(self.stride, int) or self.stride < 1:
            raise InputError(f"keyframes: stride must be an integer >= 1, got {self.stride!r}")
        for name in ("fps", "min_translation", "min_rotation", "max_similarity"):
            v = getattr(self, name)
            if v is not None and not (isinstance(v, (int, float)) and math.isfinite(v)):
                raise InputError(f"keyframes: {name} must be a finite number, got {v!r}")
        if self.fps is not None and self.fps <= 0:
            raise InputError(f"keyframes: fps must be > 0, got {self.fps}")
        for name in ("min_translation", "min_rotation"):
            v = getattr(self, name)
            if v is not None and v < 0:
                raise InputError(f"keyframes: {name} must be >= 0, got {v}")
        if self.max_similarity is not None and not -1.0 <= self.max_similarity <= 1.0:
            raise InputError(f"keyframes: max_similarity is a cosine in [-1, 1], got {self.max_similarity}")


@dataclass
class KeyframeStats:
    """How many frames a stage kept and, per reason, dropped."""

    kept: int = 0
    dropped: dict[str, int] = field(default_factory=dict)

    def drop(self, reason: str) -> None:
        self.dropped[reason] = self.dropped.get(reason, 0) + 1


def rotation_between(a: Pose, b: Pose) -> float:
    """Angle (rad) between two orientations: full 3-D when both have quaternions, else yaw only."""
    if a.quat is not None and b.quat is not None:
        dot = abs(sum(p * q for p, q in zip(a.quat, b.quat, strict=True)))
        return 2.0 * math.acos(min(1.0, dot))
    return abs((b.yaw - a.yaw + math.pi) % (2.0 * math.pi) - math.pi)


class Keyframer:
    """The keyframe rules as one stateful object, fed one frame at a time.

    Recorded ingest and live adds (a robot streaming frames to a running memory) go through the
    same object, so both keep the same frames: `pre(frame)` applies the cheap rules before the
    embedder (stride, rate, motion: motion is measured from the last frame that passed them) and
    `post(embedding)` the novelty rule after it (similarity to the last frame kept). Each returns
    None when the frame passes, or the reason it was dropped (one of the DROP_* strings).
    """

    def __init__(self, cfg: KeyframeConfig | None = None) -> None:
        self.cfg = cfg or KeyframeConfig()
        self.stats = KeyframeStats()
        self.novelty = NoveltyFilter(self.cfg.max_similarity) if self.cfg.max_similarity is not None else None
        self._seen = 0
        self._t0: float | None = None
        self._last_slot = -1
        self._last_pose: Pose | None = None

    def pre(self, f: Frame) -> str | None:
        """The cheap rules, in order: stride, rate, motion."""
        cfg = self.cfg
        i = self._seen
        self._seen += 1
        if i % cfg.stride:
            return self._drop(DROP_STRIDE)
        slot = -1
        if cfg.fps is not None:
            self._t0 = f.t if self._t0 is None else self._t0
            slot = math.floor((f.t - self._t0) * cfg.fps + 1e-6)
            if slot <= self._last_slot:
                return self._drop(DROP_FPS)
        motion = cfg.min_translation is not None or cfg.min_rotation is not None
        last = self._last_pose
        if motion and f.pose is not None and last is not None:
            moved = cfg.min_translation is not None and f.pose.distance_to(last) >= cfg.min_translation
            turned = cfg.min_rotation is not None and rotation_between(last, f.pose) >= cfg.min_rotation
            if not (moved or turned):
                return self._drop(DROP_MOTION)
        if cfg.fps is not None:
            self._last_slot = slot
        if f.pose is not None:
            self._last_pose = f.pose
        if self.novelty is None:
            self.stats.kept += 1
        return None

    def post(self, embedding: np.ndarray) -> str | None:
        """The novelty rule, on the embedding of a frame that passed `pre`."""
        if self.novelty is None:
            return None
        if not self.novelty.keep(embedding):
            return self._drop(DROP_SIMILAR)
        self.stats.kept += 1
        return None

    def _drop(self, reason: str) -> str:
        self.stats.drop(reason)
        return reason


def select_frames(
    frames: Iterable[Frame], cfg: KeyframeConfig, stats: KeyframeStats | None = None
) -> Iterator[Frame]:
    """Yield the frames that pass stride, rate and motion rules (in that order), counting drops.

    The rate rule puts frames in slots of 1/fps seconds from the first frame and keeps the first
    frame of each new slot, so timestamp jitter does not lower the kept rate. Frames without a
    pose pass the motion rule (nothing to compare) and do not reset it.
    """
    kf = Keyframer(replace(cfg, max_similarity=None))
    if stats is not None:
        kf.stats = stats
    for f in frames:
        if kf.pre(f) is None:
            yield f


class NoveltyFilter:
    """Post-embedding stage: keep an embedding unless it is within `max_similarity` of the last kept."""

    def __init__(self, max_similarity: float) -> None:
        if not -1.0 <= max_similarity <= 1.0:
            raise InputError(f"keyframes: max_similarity is a cosine in [-1, 1], got {max_similarity}")
        self.max_similarity = float(max_similarity)
        self.stats = KeyframeStats()
        self._last: np.ndarray | None = None

    def keep(self, embedding: np.ndarray) -> bool:
        """True (and remember it) when the embedding is novel enough; the first is always kept."""
        v = np.asarray(embedding, dtype=np.float64).reshape(-1)
        n = float(np.linalg.norm(v))
        v = v / n if n > 0 else v
        if self._last is not None and float(v @ self._last) > self.max_similarity:
            self.stats.drop(DROP_SIMILAR)
            return False
        self._last = v
        self.stats.kept += 1
        return True


_NUM = r"([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)"
_UNITS: dict[str, dict[str, float]] = {
    "stride": {"": 1.0},
    "fps": {"": 1.0, "hz": 1.0},
    "min_translation": {"": 1.0, "m": 1.0, "cm": 0.01, "mm": 0.001},
    "min_rotation": {"": 1.0, "rad": 1.0, "deg": math.pi / 180.0},
    "max_similarity": {"": 1.0},
}


def parse_keyframes(spec: str | None) -> KeyframeConfig:
    """Parse `stride=5,fps=2,min_translation=0.1,min_rotation=10deg,max_similarity=0.95`.

    Empty/None/'all' keeps every frame. Units: fps `hz`; translation `m`/`cm`/`mm` (default m);
    rotation `deg`/`rad` (default rad).
    """
    if spec is None or spec.strip().lower() in ("", "all", "none"):
        return KeyframeConfig()
    known = [f.name for f in fields(KeyframeConfig)]
    values: dict[str, float | int] = {}
    for part in spec.split(","):
        key, eq, raw = (s.strip() for s in part.partition("="))
        if not part.strip():
            continue
        if not eq:
            raise InputError(f"keyframes: {part.strip()!r} is not key=value (keys: {', '.join(known)})")
        if key not in known:
            raise InputError(f"keyframes: unknown key {key!r}; choose from {', '.join(known)}")
        if key in values:
            raise InputError(f"keyframes: {key} is given twice")
        m = re.fullmatch(_NUM + r"\s*([a-zA-Z]*)", raw)
        unit = m.group(2).lower() if m else ""
        if m is None or unit not in _UNITS[key]:
            units = "/".join(u for u in _UNITS[key] if u) or "no unit"
            raise InputError(f"keyframes: {key}={raw!r} is not a number (units: {units})")
        if key == "stride":
            if not re.fullmatch(r"\+?\d+", m.group(1)):
                raise InputError(f"keyframes: stride={raw!r} must be a whole number")
            values[key] = int(m.group(1))
        else:
            values[key] = float(m.group(1)) * _UNITS[key][unit]
    return KeyframeConfig(**values)  # type: ignore[arg-type]
