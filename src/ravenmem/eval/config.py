"""The settings of an evaluation run as typed, nested dataclasses, each checked when built.

A run is a dataset, the methods and their options, the models (embedder, VLM, judge), how the
memories are built, the scoring thresholds and where the rows go. Each part is its own dataclass
that validates itself in `__post_init__`, so a bad value fails with one line naming the option
before any work starts, whether the config came from the CLI, a study or Python:

    RunConfig(DatasetConfig("navqa:/data/navqa"), MethodConfig(["offline", "random"]), seeds=3)

`RunConfig.identity()` is the flat dictionary of answer-changing settings written to a run
folder's `config.json`; it keeps the keys and values earlier versions wrote (dataset, queries,
embedder, vlm, vlm_base_url, keyframes, ocr, thumb_size, method_opts, dataset_opts), so folders
written before these classes existed are still resumed and refused the same way.
"""

from __future__ import annotations

import math
import re
from dataclasses import asdict, dataclass, field, fields
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from ..errors import InputError
from ..ingest.keyframes import KeyframeConfig

TIME_MODES = ("forward", "centred")
PRESETS = ("raven-qa", "navqa", "findingdory")
RAVEN_QA = ("raven-qa", "ravenqa")
# Settings that change answers: a run folder holds one value of each (methods and seeds may grow).
IDENTITY = (
    "dataset",
    "queries",
    "embedder",
    "vlm",
    "vlm_base_url",
    "keyframes",
    "ocr",
    "thumb_size",
    "method_opts",
    "dataset_opts",
)


def _positive(name: str, value: float | None, allow_zero: bool = False) -> None:
    if value is None:
        return
    ok = math.isfinite(value) and (value >= 0 if allow_zero else value > 0)
    if not ok:
        raise InputError(f"{name} must be {'>= 0' if allow_zero else '> 0'}, got {value}")


@dataclass
class Thresholds:
    """Scoring criteria; None means the question's or the dataset's own value.

    position_m: metres (None: per question, else the dataset's: NaVQA 15 m, RAVEN-QA 2 m).
    time_s / duration_s: seconds. frame_s: seconds either side of an accepted frame (None: the
    dataset's; RAVEN-QA = the frame itself). planar: position error in x, y only.
    """

    position_m: float | None = None
    time_s: float = 30.0
    duration_s: float = 30.0
    frame_s: float | None = None
    planar: bool = False

    def __post_init__(self) -> None:
        _positive("--pos-threshold", self.position_m)
        _positive("--time-threshold", self.time_s)
        _positive("--duration-threshold", self.duration_s)
        _positive("--frame-tolerance", self.frame_s, allow_zero=True)

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None) -> Thresholds:
        return cls(**{k: v for k, v in (d or {}).items() if k in cls.__dataclass_fields__})


@dataclass
class DatasetConfig:
    """Which questions: `spec` is NAME:PATH; the other fields are the loaders' options.

    rate: RAVEN-QA frames per second where no timestamps are given. tz: NaVQA time zone of
    data.csv. split: FindingDory split name. pos_threshold: RAVEN-QA metres per subset folder
    ({"real_world": 3}). episodes: a glob over episode ids. limit: the first N questions.
    """

    spec: str
    queries: str | None = None
    rate: float | None = None
    tz: str | None = None
    split: str | None = None
    pos_threshold: dict[str, float] | None = None
    episodes: str | None = None
    limit: int | None = None

    def __post_init__(self) -> None:
        name, sep, path = self.spec.partition(":")
        if not sep or not name or not path:
            raise InputError(
                f"--dataset: expected NAME:PATH (e.g. raven-qa:/data/RAVEN_QA), got {self.spec!r}"
            )
        _positive("--rate", self.rate)
        if self.limit is not None and self.limit < 1:
            raise InputError(f"--limit must be >= 1, got {self.limit}")
        if self.pos_threshold is not None:
            if self.kind not in RAVEN_QA:
                raise InputError("--pos-threshold subset=value,... is for raven-qa datasets; give one number")
            for key, val in self.pos_threshold.items():
                _positive(f"--pos-threshold {key}", val)

    @property
    def kind(self) -> str:
        return self.spec.partition(":")[0]

    def options(self) -> dict[str, Any]:
        """The loader's keyword options that are set (part of the run's identity)."""
        opts = {"rate": self.rate, "tz": self.tz, "split": self.split, "pos_threshold": self.pos_threshold}
        return {k: v for k, v in opts.items() if v is not None}


@dataclass
class MethodConfig:
    """Which methods answer, and the options every method is built with (each takes what it uses).

    The option names are the methods' own keyword arguments: `top_k` (one k, or {tool: k}),
    `max_tool_calls`, `frames` (vlm-only), `show_scores`, `time_mode` ("forward" | "centred"),
    `preset` ("raven-qa" | "navqa" | "findingdory"), `temperature` and `image_max_side` (the
    longest side of the pictures sent to the model; the stored size is `MemoryConfig.thumb_size`).
    The seed is the run's.
    """

    names: list[str]
    top_k: int | dict[str, int] | None = None
    max_tool_calls: int | None = None
    frames: int | None = None
    show_scores: bool | None = None
    time_mode: str | None = None
    preset: str | None = None
    temperature: float | None = None
    image_max_side: int | None = None

    def __post_init__(self) -> None:
        self.names = [n.strip() for n in self.names if n and n.strip()]
        if not self.names:
            raise InputError("--method: give at least one method")
        ks = self.top_k.values() if isinstance(self.top_k, dict) else [self.top_k]
        if any(k is not None and (isinstance(k, bool) or not isinstance(k, int) or k < 1) for k in ks):
            raise InputError(f"--top-k: whole numbers >= 1, got {self.top_k}")
        for name, val in (("--max-tool-calls", self.max_tool_calls), ("--frames", self.frames)):
            if val is not None and val < (0 if name == "--max-tool-calls" else 1):
                raise InputError(f"{name} must be >= {0 if name == '--max-tool-calls' else 1}, got {val}")
        if self.time_mode is not None and self.time_mode not in TIME_MODES:
            raise InputError(f"--time-mode: one of {', '.join(TIME_MODES)}, got {self.time_mode!r}")
        if self.preset is not None and self.preset not in PRESETS:
            raise InputError(f"--preset: one of {', '.join(PRESETS)}, got {self.preset!r}")
        _positive("--temperature", self.temperature, allow_zero=True)
        if self.image_max_side is not None and self.image_max_side < 16:
            raise InputError(f"--image-max-side must be >= 16 px, got {self.image_max_side}")

    def options(self) -> dict[str, Any]:
        """The method options that are set (handed to every method; part of the run's identity)."""
        return {
            f.name: getattr(self, f.name)
            for f in fields(self)
            if f.name != "names" and getattr(self, f.name) is not None
        }


@dataclass
class ModelConfig:
    """The embedder that builds the memories, the VLM the agent methods talk to, the text judge."""

    embedder: str = "offline"
    vlm: str | None = None
    vlm_base_url: str | None = None
    judge: str | None = None
    judge_base_url: str | None = None

    def __post_init__(self) -> None:
        if not self.embedder.strip():
            raise InputError("--embedder: give an embedder (offline, open_clip:..., hf:...)")


@dataclass
class MemoryConfig:
    """How each episode's memory is built (and where built memories and vectors are cached).

    keyframes: a --keyframes spec; None keeps every frame, whatever ingest's own defaults are.
    """

    keyframes: str | None = None
    ocr: bool = False
    thumb_size: int = 320
    cache_dir: str = ".ravenmem-cache/eval"

    def __post_init__(self) -> None:
        self.keyframe_config()
        if self.thumb_size < 16:
            raise InputError(f"--thumb-size must be >= 16 px, got {self.thumb_size}")

    def keyframe_config(self) -> KeyframeConfig:
        return eval_keyframes(self.keyframes)


@dataclass
class OutputConfig:
    """Where the run folder is: `out`, else `runs_dir/<date>/<name or a name from the settings>`."""

    out: str | None = None
    runs_dir: str = "runs"
    name: str | None = None


@dataclass
class RunConfig:
    """One evaluation run: the parts above plus seeds, parallelism and a study's variant label."""

    dataset: DatasetConfig
    methods: MethodConfig
    models: ModelConfig = field(default_factory=ModelConfig)
    memory: MemoryConfig = field(default_factory=MemoryConfig)
    thresholds: Thresholds = field(default_factory=Thresholds)
    output: OutputConfig = field(default_factory=OutputConfig)
    seeds: int = 1
    workers: int = 4
    retry_failed: bool = False
    progress: bool | None = None
    variant: str = ""  # separates rows of otherwise equal settings in reports (studies)

    def __post_init__(self) -> None:
        if self.seeds < 1 or self.workers < 1:
            raise InputError(f"--seeds and --workers must be >= 1 (got {self.seeds}, {self.workers})")

    def run_dir(self) -> Path:
        if self.output.out:
            return Path(self.output.out)
        emb = self.models.embedder.rsplit("/", 1)[-1]
        parts = (self.dataset.kind, "+".join(self.methods.names), emb, self.models.vlm or "")
        name = self.output.name or "_".join(p for p in parts if p)
        day = datetime.now(timezone.utc).strftime("%Y-%m-%d")
        return Path(self.output.runs_dir) / day / re.sub(r"[^A-Za-z0-9._+-]+", "-", name)

    def identity(self) -> dict[str, Any]:
        """The answer-changing settings, flat, under the keys config.json has always used."""
        return {
            "dataset": self.dataset.spec,
            "queries": self.dataset.queries,
            "embedder": self.models.embedder,
            "vlm": self.models.vlm,
            "vlm_base_url": self.models.vlm_base_url,
            "keyframes": self.memory.keyframes,
            "ocr": self.memory.ocr,
            "thumb_size": self.memory.thumb_size,
            "method_opts": self.methods.options(),
            "dataset_opts": self.dataset.options(),
        }

    def to_json(self) -> dict[str, Any]:
        """config.json: the identity keys at the top (as before), then the whole nested config."""
        return self.identity() | {
            "methods": list(self.methods.names),
            "seeds": self.seeds,
            "thresholds": self.thresholds.to_dict(),
            "config": asdict(self),
        }


def eval_keyframes(spec: str | None) -> KeyframeConfig:
    """A --keyframes spec as every front end reads it (`KeyframeConfig.from_spec`), except that
    eval's own default is every frame (`all`): the benchmarks' layouts are scored per frame."""
    return KeyframeConfig.from_spec(spec if spec is not None and spec.strip() else "all")
