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
from collections.abc import Callable, Mapping
from dataclasses import MISSING, asdict, dataclass, field, fields
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

from ..agent.presets import PRESETS, RENAMED, parse_top_k
from ..errors import InputError
from ..ingest.keyframes import KeyframeConfig
from ..spec import pairs

TIME_MODES = ("forward", "centred", "nearest")
SCORING = ("paper", "release")
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


def option(
    flag: str,
    help: str,
    default: Any = None,
    *,
    cli: Any = None,
    parse: Callable[[Any], Any] | None = None,
    name: str | None = None,
) -> Any:
    """A config field that is also a command-line option of every command that runs questions.

    `flag` is the option ("--top-k", or "--ocr/--no-ocr" for a switch), `cli` the type the
    command line takes when it is not the field's own (e.g. `str` for a `{tool: k}` mapping),
    `parse` turns the command-line value into the field's value, `name` is the parameter name
    when it is not the field's. `ravenmem.cli.eval` builds its options from these, so the config
    is the one place an option is declared."""
    meta = {"flag": flag, "help": help, "cli": cli, "parse": parse, "name": name}
    if isinstance(default, (dict, list)):
        return field(default_factory=lambda: type(default)(default), metadata=meta)
    return field(default=default, metadata=meta)


def options_of(cls: type) -> list[Any]:
    """The fields of a config class that are command-line options."""
    return [f for f in fields(cls) if "flag" in f.metadata]


def _positive(name: str, value: float | None, allow_zero: bool = False) -> None:
    if value is None:
        return
    ok = math.isfinite(value) and (value >= 0 if allow_zero else value > 0)
    if not ok:
        raise InputError(f"{name} must be {'>= 0' if allow_zero else '> 0'}, got {value}")


def _floats(text: str, what: str) -> list[float]:
    try:
        return [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise InputError(f"{what}: expected numbers, got {text!r}") from None


def parse_pos_threshold(text: str | float | None) -> float | dict[str, float] | None:
    """'2.5' -> 2.5; 'real_world=3,habitat_sim=1' -> {'real_world': 3.0, 'habitat_sim': 1.0}."""
    if text is None or isinstance(text, (int, float)):
        return text
    if "=" not in text:
        vals = _floats(text, "--pos-threshold")
        if len(vals) != 1:
            raise InputError(f"--pos-threshold: one number or subset=metres,..., got {text!r}")
        return vals[0]
    given = pairs(
        text,
        "--pos-threshold",
        bad="{what}: expected subset=metres, got {part!r}",
        repeat=True,
        empty_value=True,
    )
    return {key: _floats(val, "--pos-threshold")[0] if val else math.nan for key, val in given.items()}


def _minutes(value: float | None) -> float | None:
    return None if value is None else 60.0 * value


def _names(text: str | list[str] | None) -> list[str]:
    items = text if isinstance(text, list) else (text or "").split(",")
    return [n.strip() for n in items if n and n.strip()]


@dataclass
class Thresholds:
    """Scoring criteria; None means the question's or the dataset's own value.

    position_m: metres, one number or {subset: metres} (None: per question, else the dataset's:
    NaVQA 15 m, RAVEN-QA 2 m). time_s / duration_s: seconds. frame_s: seconds either side of an
    accepted frame (None: the dataset's; RAVEN-QA = the frame itself). planar: position error in
    x, y only. scoring: "paper" (the papers' headline criteria) or "release" (the rule of the
    benchmark release's own scorer; see `ravenmem.eval.metrics`).
    """

    position_m: float | dict[str, float] | None = option(
        "--pos-threshold",
        "metres: one number, or per RAVEN-QA subset 'real_world=3,habitat_sim=1'",
        cli=str,
        parse=parse_pos_threshold,
        name="pos_threshold",
    )
    time_s: float = option(
        "--time-threshold", "minutes (default 0.5)", 30.0, cli=float, parse=_minutes, name="time_threshold"
    )
    duration_s: float = option(
        "--duration-threshold",
        "minutes (default 0.5)",
        30.0,
        cli=float,
        parse=_minutes,
        name="duration_threshold",
    )
    frame_s: float | None = option(
        "--frame-tolerance", "seconds either side of an accepted frame", name="frame_tolerance"
    )
    planar: bool = option("--planar/--no-planar", "position error in x, y only", False)
    scoring: str = option(
        "--scoring",
        "paper (the papers' headline criteria, default) | release (the benchmark release's own scorer)",
        "paper",
    )

    def __post_init__(self) -> None:
        if isinstance(self.position_m, Mapping):
            self.position_m = {str(k): float(v) for k, v in self.position_m.items()}
            for key, val in self.position_m.items():
                _positive(f"--pos-threshold {key}", val)
        else:
            _positive("--pos-threshold", self.position_m)
        _positive("--time-threshold", self.time_s)
        _positive("--duration-threshold", self.duration_s)
        _positive("--frame-tolerance", self.frame_s, allow_zero=True)
        if self.scoring not in SCORING:
            raise InputError(f"--scoring: one of {', '.join(SCORING)}, got {self.scoring!r}")

    def position_for(self, subset: str = "") -> float | None:
        """The user's position threshold for a question of this subset (None: not given)."""
        if isinstance(self.position_m, dict):
            return self.position_m.get(subset)
        return self.position_m

    def check_subsets(self, subsets: set[str]) -> None:
        """Refuse per-subset thresholds naming a subset the dataset does not have."""
        if not isinstance(self.position_m, dict):
            return
        unknown = sorted(set(self.position_m) - subsets)
        if unknown:
            have = ", ".join(sorted(s for s in subsets if s)) or "none"
            raise InputError(
                f"--pos-threshold: no subset named {', '.join(unknown)} in this dataset (its subsets: {have})"
            )

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict[str, Any] | None) -> Thresholds:
        return cls(**{k: v for k, v in (d or {}).items() if k in cls.__dataclass_fields__})


@dataclass
class DatasetConfig:
    """Which questions: `spec` is NAME:PATH; the other fields are the loaders' options.

    rate: RAVEN-QA frames per second where no timestamps are given. tz: NaVQA time zone of
    data.csv (None: the zone of the release the layout identifies). split: FindingDory split
    name. episodes: a glob over episode ids. limit: the first N questions.
    """

    spec: str = option(
        "--dataset -d",
        "NAME:PATH, NAME = raven-qa | navqa | findingdory | tum | video | folder | rosbag | memory | queries",
        name="dataset",
    )
    queries: str | None = option(
        "--queries", "our questions.json for tum:/video:/folder:/rosbag:/memory: datasets"
    )
    rate: float | None = option("--rate", "raven-qa: frames per second where no timestamps are given")
    tz: str | None = option(
        "--tz", "navqa: time zone of data.csv (default: the release's, UTC-5 RAVEN, UTC-8 ReMEmbR)"
    )
    split: str | None = option("--split", "findingdory: split name (validation)")
    episodes: str | None = option("--episodes", "only episodes whose id matches this glob")
    limit: int | None = option("--limit", "only the first N questions (smoke runs)")

    def __post_init__(self) -> None:
        if not self.spec:
            raise InputError("--dataset NAME:PATH is required (e.g. raven-qa:/data/RAVEN_QA/real_world)")
        name, sep, path = self.spec.partition(":")
        if not sep or not name or not path:
            raise InputError(
                f"--dataset: expected NAME:PATH (e.g. raven-qa:/data/RAVEN_QA), got {self.spec!r}"
            )
        _positive("--rate", self.rate)
        if self.limit is not None and self.limit < 1:
            raise InputError(f"--limit must be >= 1, got {self.limit}")

    @property
    def kind(self) -> str:
        return self.spec.partition(":")[0]

    def options(self) -> dict[str, Any]:
        """The loader's keyword options that are set (part of the run's identity)."""
        opts = {"rate": self.rate, "tz": self.tz, "split": self.split}
        return {k: v for k, v in opts.items() if v is not None}


@dataclass
class MethodConfig:
    """Which methods answer, and the options every method is built with (each takes what it uses).

    The option names are the methods' own keyword arguments: `top_k` (one k, or {tool: k}),
    `max_tool_calls`, `frames` (vlm-only), `show_scores`, `time_mode` ("forward" | "centred" |
    "nearest"), `preset` (see `ravenmem.agent.presets`), `temperature`, `image_max_side` (the
    longest side of the pictures sent to the model; the stored size is `MemoryConfig.thumb_size`)
    and `encoder` (the caption baseline's text encoder). The seed is the run's.
    """

    names: list[str] = option(
        "--method",
        "comma-separated: raven, offline, embedder-only, vlm-only, caption, random",
        [],
        cli=str,
        parse=_names,
        name="method",
    )
    top_k: int | dict[str, int] | None = option(
        "--top-k",
        "memories per tool call: N, or per tool 'time=200,text=30,position=1'",
        cli=str,
        parse=parse_top_k,
    )
    max_tool_calls: int | None = option("--max-tool-calls", "tool calls before the model must answer")
    frames: int | None = option(
        "--frames", "vlm-only: most frames shown (sampled over the history; default 1500, the release's)"
    )
    show_scores: bool | None = option("--show-scores/--hide-scores", "similarity scores shown to the model")
    time_mode: str | None = option(
        "--time-mode", "time tool: forward (from the time on) | centred (around it) | nearest (nearest first)"
    )
    preset: str | None = option("--preset", "the paper's settings: " + " | ".join(PRESETS))
    temperature: float | None = option("--temperature", "the VLM's sampling temperature")
    image_max_side: int | None = option(
        "--image-max-side", "longest side in px of images sent to the model (default: as stored)"
    )
    encoder: str | None = option(
        "--caption-encoder",
        "caption baseline: text encoder, minilm (default) or a sentence-transformers name or folder "
        "(e.g. mixedbread-ai/mxbai-embed-large-v1, as in the paper's ReMEmbR rows)",
        name="caption_encoder",
    )

    def __post_init__(self) -> None:
        self.names = _names(self.names)
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
            if self.preset in RENAMED:
                raise InputError(
                    f"--preset {self.preset}: the paper's table has one per kind of video: {RENAMED[self.preset]}"
                )
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

    embedder: str = option("--embedder", "offline | open_clip:MODEL/TAG | hf:NAME_OR_PATH", "offline")
    vlm: str | None = option("--vlm", "VLM model name (endpoint from --vlm-base-url / RAVENMEM_VLM_BASE_URL)")
    vlm_base_url: str | None = option("--vlm-base-url", "OpenAI-compatible endpoint for the VLM")
    judge: str | None = option("--judge", "LLM judge model for text answers")
    judge_base_url: str | None = option("--judge-base-url", "endpoint of the judge (default: the VLM's)")

    def __post_init__(self) -> None:
        if not self.embedder.strip():
            raise InputError("--embedder: give an embedder (offline, open_clip:..., hf:...)")


@dataclass
class MemoryConfig:
    """How each episode's memory is built (and where built memories and vectors are cached).

    keyframes: a --keyframes spec; None keeps every frame, whatever ingest's own defaults are.
    """

    keyframes: str | None = option(
        "--keyframes", "e.g. 'stride=5,fps=2,max_similarity=0.95' (default: all frames)"
    )
    ocr: bool = option("--ocr/--no-ocr", "read text in keyframes while building memories (slower)", False)
    thumb_size: int = option("--thumb-size", "thumbnail longer side (px) in built memories", 320)
    cache_dir: str = option("--cache-dir", "where memories and embeddings are cached", ".ravenmem-cache/eval")

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


SECTIONS: dict[str, type] = {
    "dataset": DatasetConfig,
    "methods": MethodConfig,
    "models": ModelConfig,
    "memory": MemoryConfig,
    "thresholds": Thresholds,
    "output": OutputConfig,
}


@dataclass
class RunConfig:
    """One evaluation run: the parts above plus seeds, parallelism and a study's variant label."""

    dataset: DatasetConfig
    methods: MethodConfig
    models: ModelConfig = field(default_factory=ModelConfig)
    memory: MemoryConfig = field(default_factory=MemoryConfig)
    thresholds: Thresholds = field(default_factory=Thresholds)
    output: OutputConfig = field(default_factory=OutputConfig)
    seeds: int = option("--seeds", "repeat every question with seeds 0..N-1 (mean ± std)", 1)
    workers: int = option("--workers", "questions answered in parallel", 4)
    retry_failed: bool = option(
        "--retry-failed/--no-retry-failed", "answer again the questions whose method failed", False
    )
    progress: bool | None = None
    variant: str = ""  # separates rows of otherwise equal settings in reports (studies)

    def __post_init__(self) -> None:
        if self.seeds < 1 or self.workers < 1:
            raise InputError(f"--seeds and --workers must be >= 1 (got {self.seeds}, {self.workers})")

    @classmethod
    def from_dict(cls, d: Mapping[str, Any]) -> RunConfig:
        """A RunConfig from `asdict` output (the `config` of config.json / manifest.json)."""
        parts: dict[str, Any] = {}
        for name, section in SECTIONS.items():
            known = {f.name for f in fields(section)}
            raw = d.get(name) or {}
            parts[name] = section(**{k: v for k, v in raw.items() if k in known})
        top = {f.name for f in fields(cls)} - set(SECTIONS)
        return cls(**parts, **{k: v for k, v in d.items() if k in top})

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


def field_default(f: Any) -> Any:
    """A dataclass field's default value (None when it has none)."""
    if f.default is not MISSING:
        return f.default
    if f.default_factory is not MISSING:
        return f.default_factory()
    return None


def option_name(f: Any) -> str:
    """The parameter (and `values` key) of a config option: its `name`, else the field's."""
    return str(f.metadata.get("name") or f.name)


def _given(cls: type, values: Mapping[str, Any], base: Any = None) -> dict[str, Any]:
    """A section's keyword arguments: `base`'s values, overlaid by the options given."""
    kw = asdict(base) if base is not None else {}
    for f in options_of(cls):
        v = values.get(option_name(f))
        if v is not None:
            parse = f.metadata.get("parse")
            kw[f.name] = parse(v) if parse else v
    return kw


def build_run_config(values: Mapping[str, Any], base: RunConfig | None = None) -> RunConfig:
    """The RunConfig from option values by parameter name (None = not given), over `base` when
    given (a replayed run's recorded settings): where command-line values become a config."""
    parts = {
        name: cls(**_given(cls, values, getattr(base, name) if base else None))
        for name, cls in SECTIONS.items()
        if name != "output"
    }
    top = _given(RunConfig, values)
    if base is not None:
        top = {f.name: getattr(base, f.name) for f in options_of(RunConfig)} | top
    return RunConfig(**parts, output=base.output if base is not None else OutputConfig(), **top)


def thresholds_from(values: Mapping[str, Any], base: Thresholds) -> Thresholds:
    """`base` (a run's thresholds) overlaid by the threshold options given (reports re-score)."""
    return Thresholds(**_given(Thresholds, values, base))


def eval_keyframes(spec: str | None) -> KeyframeConfig:
    """A --keyframes spec as every front end reads it (`KeyframeConfig.from_spec`), except that
    eval's own default is every frame (`all`): the benchmarks' layouts are scored per frame."""
    return KeyframeConfig.from_spec(spec if spec is not None and spec.strip() else "all")
