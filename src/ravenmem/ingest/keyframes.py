"""Keyframe selection: keep few, informative frames before paying for embeddings.

Two stages. The cheap one runs before the embedder: a stride, a target rate from timestamps, and
pose motion (keep when the camera moved or turned enough since the last candidate, or when
`max_interval` seconds passed without that, so that a still camera still looks now and then).
The novelty stage runs after the embedder: drop a frame whose embedding is too similar (cosine)
to the last keyframe, unless that keyframe is older than `novelty_window` seconds, so a robot
parked in front of a wall stores one memory per window, not 1000. Each stage counts what it
dropped and why.

`KeyframeConfig()` is the default rule set (measured on TUM fr1_rpy: docs/ingest.md, Keyframes),
and what every front end uses when given no keyframe option; `KeyframeConfig.only()` keeps every
frame; `KeyframeConfig.from_spec(spec)` reads a `--keyframes` spec.
"""

from __future__ import annotations

import math
import re
from collections import deque
from collections.abc import Iterable, Iterator
from dataclasses import dataclass, field, fields, replace

import numpy as np

from ..errors import InputError
from ..spec import pairs, parts
from ..types import Frame, Pose

DROP_STRIDE = "stride"
DROP_FPS = "above target fps"
DROP_MOTION = "too little motion"
DROP_SIMILAR = "similar to last keyframe"


# The defaults, chosen on TUM fr1_rpy (benchmarks/bench_keyframes.py; docs/ingest.md, Keyframes).
DEFAULT_MIN_TRANSLATION = 0.5  # m
DEFAULT_MIN_ROTATION = math.radians(15.0)
DEFAULT_MAX_INTERVAL = 5.0  # s
DEFAULT_MAX_SIMILARITY = 0.97
DEFAULT_NOVELTY_WINDOW = 30.0  # s
NUMERIC_KEYS = ("fps", "min_translation", "min_rotation", "max_interval", "max_similarity", "novelty_window")


_NUM = r"([-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?)"
_UNITS: dict[str, dict[str, float]] = {
    "stride": {"": 1.0},
    "fps": {"": 1.0, "hz": 1.0},
    "min_translation": {"": 1.0, "m": 1.0, "cm": 0.01, "mm": 0.001},
    "min_rotation": {"": 1.0, "rad": 1.0, "deg": math.pi / 180.0},
    "max_interval": {"": 1.0, "s": 1.0, "ms": 0.001, "min": 60.0},
    "max_similarity": {"": 1.0},
    "novelty_window": {"": 1.0, "s": 1.0, "ms": 0.001, "min": 60.0},
}


@dataclass
class KeyframeConfig:
    """Selection rules; None disables a rule. `KeyframeConfig()` is the default rule set,
    `KeyframeConfig.only()` keeps every frame.

    stride: keep every n-th incoming frame. fps: at most this many frames per second of source
    time. min_translation (m) / min_rotation (rad): keep a frame when it moved at least this far
    OR turned at least this much since the last frame that passed (the first frame always
    passes); max_interval (s): also pass a frame when this long has gone by without one (a still
    camera keeps looking; needs a motion rule to mean anything). max_similarity: after
    embedding, drop a frame whose cosine similarity to the last keyframe is above this, unless
    that keyframe is more than `novelty_window` seconds old (None: however old).
    """

    stride: int = 1
    fps: float | None = None
    min_translation: float | None = DEFAULT_MIN_TRANSLATION
    min_rotation: float | None = DEFAULT_MIN_ROTATION
    max_interval: float | None = DEFAULT_MAX_INTERVAL
    max_similarity: float | None = DEFAULT_MAX_SIMILARITY
    novelty_window: float | None = DEFAULT_NOVELTY_WINDOW

    @classmethod
    def only(cls, **rules: float | int | None) -> KeyframeConfig:
        """Exactly the rules given, every other rule off: `only()` keeps every frame (`--keyframes
        all`), `only(stride=5)` every 5th. (`KeyframeConfig(stride=5)` is the defaults plus a stride.)"""
        off: dict[str, float | int | None] = dict.fromkeys(NUMERIC_KEYS)
        return cls(**(off | rules))  # type: ignore[arg-type]

    @classmethod
    def from_spec(cls, spec: str | None) -> KeyframeConfig:
        """The rules a `--keyframes` spec names: `default`, `all`, or rules such as
        `fps=2,min_rotation=10deg`.

        No spec (None or empty) and `default` are the default rules, `KeyframeConfig()`, for
        every front end alike (ingest, serve, the ROS 2 node, the Python API); `all` keeps every
        frame; `default,key=value,...` changes some of the default rules; rules named without
        `default` are the only ones used. Units: fps `hz`; translation `m`/`cm`/`mm` (default
        m); rotation `deg`/`rad` (default rad); max_interval and novelty_window `s`/`ms`/`min`
        (default s).
        """
        if spec is None or spec.strip().lower() in ("", "default"):
            return cls()
        if spec.strip().lower() in ("all", "none"):
            return cls.only()
        known = [f.name for f in fields(cls)]
        given = parts(spec)
        base = cls.only()
        if given and given[0].lower() == "default":
            base, given = cls(), given[1:]
        values: dict[str, float | int] = {}
        rules = pairs(given, "keyframes", known=known, hint="; or 'default', 'all'", empty_value=True)
        for key, raw in rules.items():
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
        return replace(base, **values)  # type: ignore[arg-type]

    def __post_init__(self) -> None:
        if isinstance(self.stride, bool) or not isinstance(self.stride, int) or self.stride < 1:
            raise InputError(f"keyframes: stride must be an integer >= 1, got {self.stride!r}")
        for name in NUMERIC_KEYS:
            v = getattr(self, name)
            if v is not None and (
                isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v)
            ):
                raise InputError(f"keyframes: {name} must be a finite number, got {v!r}")
        for name in ("fps", "max_interval", "novelty_window"):
            v = getattr(self, name)
            if v is not None and v <= 0:
                raise InputError(f"keyframes: {name} must be > 0, got {v}")
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
    return a.rotation_to(b)


class Keyframer:
    """The keyframe rules as one stateful object, fed one frame at a time.

    Recorded ingest and live adds (a robot streaming frames to a running memory) go through the
    same object, so both keep the same frames: `pre(frame)` applies the cheap rules before the
    embedder (stride, rate, motion: motion is measured from the last frame that passed them) and
    `post(embedding)` the novelty rule after it (similarity to the last keyframe, if it is not
    older than `novelty_window` seconds). Each returns None when the frame passes, or the reason it was
    dropped (one of the DROP_* strings). Every frame that passes `pre` gets exactly one `post`
    call, in the same order (a batch of `pre` calls then their `post` calls is fine).
    """

    def __init__(self, cfg: KeyframeConfig | None = None) -> None:
        self.cfg = cfg or KeyframeConfig()
        self.stats = KeyframeStats()
        self.novelty = (
            NoveltyFilter(self.cfg.max_similarity, self.cfg.novelty_window)
            if self.cfg.max_similarity is not None
            else None
        )
        self._seen = 0
        self._t0: float | None = None
        self._last_slot = -1
        self._last_pose: Pose | None = None
        self._last_t: float | None = None
        self._pending: deque[float] = deque()  # times of frames that passed `pre`, awaiting `post`

    def pre(self, f: Frame) -> str | None:
        """The cheap rules, in order: stride, rate, motion (or max_interval elapsed)."""
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
            waited = (
                cfg.max_interval is not None
                and self._last_t is not None
                and f.t - self._last_t >= cfg.max_interval
            )
            if not (moved or turned or waited):
                return self._drop(DROP_MOTION)
        if cfg.fps is not None:
            self._last_slot = slot
        if f.pose is not None:
            self._last_pose = f.pose
            self._last_t = f.t
        if self.novelty is None:
            self.stats.kept += 1
        else:
            self._pending.append(f.t)
        return None

    def post(self, embedding: np.ndarray) -> str | None:
        """The novelty rule, on the embedding of the oldest frame that passed `pre` without one."""
        if self.novelty is None:
            return None
        t = self._pending.popleft() if self._pending else None
        if not self.novelty.keep(embedding, t):
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
    kf = Keyframer(replace(cfg, max_similarity=None, novelty_window=None))
    if stats is not None:
        kf.stats = stats
    for f in frames:
        if kf.pre(f) is None:
            yield f


class NoveltyFilter:
    """Post-embedding stage: keep an embedding unless it is within `max_similarity` (cosine) of
    the last kept one. With a `window` (s) and frame times, a last keyframe older than the window
    no longer counts, so a scene that stays the same is stored again once per window.

    Only the last keyframe is compared, on purpose: comparing against every keyframe of the last
    3-10 s also dropped views the camera came back to, and with them the answers to "when did I
    last see X" (measured on TUM fr1_rpy: docs/ingest.md, Keyframes).
    """

    def __init__(self, max_similarity: float, window: float | None = None) -> None:
        if not -1.0 <= max_similarity <= 1.0:
            raise InputError(f"keyframes: max_similarity is a cosine in [-1, 1], got {max_similarity}")
        self.max_similarity = float(max_similarity)
        self.window = window
        self.stats = KeyframeStats()
        self._last: np.ndarray | None = None
        self._last_t: float | None = None

    def keep(self, embedding: np.ndarray, t: float | None = None) -> bool:
        """True (and remember it) when the embedding is novel enough; the first is always kept."""
        v = np.asarray(embedding, dtype=np.float64).reshape(-1)
        n = float(np.linalg.norm(v))
        v = v / n if n > 0 else v
        expired = (
            self.window is not None
            and t is not None
            and self._last_t is not None
            and t - self._last_t > self.window
        )
        if self._last is not None and not expired and float(v @ self._last) > self.max_similarity:
            self.stats.drop(DROP_SIMILAR)
            return False
        self._last, self._last_t = v, t
        self.stats.kept += 1
        return True


def describe(cfg: KeyframeConfig) -> str:
    """The rules in words with units, e.g. for `ravenmem ingest` output."""
    if cfg == KeyframeConfig.only():
        return "every frame"
    parts = []
    if cfg.stride > 1:
        parts.append(f"every {cfg.stride}th frame")
    if cfg.fps is not None:
        parts.append(f"at most {cfg.fps:g} per s")
    motion = []
    if cfg.min_translation is not None:
        motion.append(f"moved {cfg.min_translation:g} m")
    if cfg.min_rotation is not None:
        motion.append(f"turned {math.degrees(cfg.min_rotation):g} deg")
    if motion and cfg.max_interval is not None:
        motion.append(f"{cfg.max_interval:g} s passed")
    if motion:
        parts.append(" or ".join(motion))
    if cfg.max_similarity is not None:
        within = f" (if under {cfg.novelty_window:g} s old)" if cfg.novelty_window is not None else ""
        parts.append(f"cosine <= {cfg.max_similarity:g} to the last keyframe{within}")
    return "; ".join(parts)
