"""Per-benchmark agent settings, in one place: the paper's appendix table of hyperparameters.

    from ravenmem.agent import create_method
    agent = create_method("raven", mem, preset="findingdory")          # 15 calls, time k=200, ...
    agent = create_method("raven", mem, preset="navqa", top_k=8)        # explicit options win

From the RAVEN paper's appendix table (and the release's configs that ran it): 3 tool calls and
k=5 per tool for RAVEN-QA and NaVQA; 15 calls for FindingDory, whose questions span whole
episodes, with k=200 for the time tool, 30 for the text tool and 1 for the position tool (5 for
the image tool, which FindingDory does not use). Temperatures: 0.0001 for RAVEN-QA's human-ego
videos (the irs / irs_hard subsets, the simple and hard splits), 0.6 for its robot-ego videos
(habitat_sim, real_world) with closed models and 0.5 with open ones, where k is 1; 0.7 for
FindingDory and NaVQA. The VLM-only baseline sees up to 1,500 frames (3,000 for FindingDory; 20
with open models), as the release ran it. Presets ask the text and image tools for exactly k
memories (`diverse=False`: no near-duplicates dropped), as the paper's top-k is. The seed is 0
(repeatable where the server honours one); the evaluation replaces it with the run's seed.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any, ClassVar

from ..errors import InputError
from ..spec import pairs


def _each(k: int) -> dict[str, int]:
    return {"text": k, "image": k, "time": k, "position": k}


@dataclass(frozen=True)
class Preset:
    """One row of the paper's table. `frames`: the VLM-only baseline's frame cap. `diverse`:
    whether the text and image tools drop near-duplicate hits (False: exactly k)."""

    name: str
    max_tool_calls: int
    top_k: Mapping[str, int]
    temperature: float
    frames: int
    diverse: bool = False
    seed: int = 0
    about: str = ""
    # options a method may not take yet in this version: handed over where it does (the runner
    # says when the agent cannot apply one)
    hooks: ClassVar[tuple[str, ...]] = ("diverse",)

    def options(self) -> dict[str, Any]:
        """The method options this preset sets (`create_method` merges them under explicit ones;
        each method takes the ones it uses)."""
        return {
            "max_tool_calls": self.max_tool_calls,
            "top_k": dict(self.top_k),
            "temperature": self.temperature,
            "seed": self.seed,
            "frames": self.frames,
            "diverse": self.diverse,
        }


PRESETS: dict[str, Preset] = {
    p.name: p
    for p in (
        Preset(
            "raven-qa-human",
            3,
            _each(5),
            0.0001,
            1500,
            about="RAVEN-QA human-ego videos (irs, irs_hard: simple, hard): 3 tool calls, k=5, temperature 0.0001",
        ),
        Preset(
            "raven-qa-robot",
            3,
            _each(5),
            0.6,
            1500,
            about="RAVEN-QA robot-ego videos (habitat_sim, real_world), closed models: 3 tool calls, k=5, temperature 0.6",
        ),
        Preset(
            "raven-qa-robot-open",
            3,
            _each(1),
            0.5,
            20,
            about="RAVEN-QA robot-ego videos with open models: 3 tool calls, k=1, temperature 0.5, vlm-only 20 frames",
        ),
        Preset("navqa", 3, _each(5), 0.7, 1500, about="NaVQA: 3 tool calls, k=5, temperature 0.7"),
        Preset(
            "findingdory",
            15,
            {"text": 30, "image": 5, "time": 200, "position": 1},
            0.7,
            3000,
            about="FindingDory: 15 tool calls; time 200, text 30, image 5, position 1 memories per call; "
            "temperature 0.7; vlm-only 3,000 frames",
        ),
    )
}
RENAMED = {
    "raven-qa": "raven-qa-human (irs, irs_hard), raven-qa-robot (habitat_sim, real_world) or raven-qa-robot-open"
}


def get_preset(name: str | Preset | None) -> Preset | None:
    if name is None or isinstance(name, Preset):
        return name
    preset = PRESETS.get(name)
    if preset is None and name in RENAMED:
        raise InputError(f"preset {name!r}: the paper's table has one per kind of video: {RENAMED[name]}")
    if preset is None:
        raise InputError(f"unknown preset {name!r}; choose one of: {', '.join(PRESETS)}")
    return preset


def apply_preset(preset: str | Preset | None, opts: Mapping[str, Any]) -> dict[str, Any]:
    """The preset's options overlaid by the explicit ones (None means "not given"). A per-tool
    `top_k` mapping overrides only the tools it names ("findingdory, but time=100")."""
    p = get_preset(preset)
    given = {k: v for k, v in opts.items() if v is not None}
    if p is None:
        return given
    merged = {**p.options(), **given, "preset": p.name}
    merged["top_k"] = merge_top_k(p.top_k, given.get("top_k"))
    return merged


def merge_top_k(base: Mapping[str, int], given: int | Mapping[str, int] | None) -> int | dict[str, int]:
    """`given` over a preset's per-tool k: one number replaces all, a mapping only what it names."""
    if given is None:
        return dict(base)
    if isinstance(given, Mapping):
        return {**base, **given}
    return given


def parse_top_k(text: str | None) -> int | dict[str, int] | None:
    """'5' -> 5; 'time=200,text=30,position=1' -> {'time': 200, 'text': 30, 'position': 1}.

    Tool names are checked later by the agent (`per_tool_k`); here only the shape and numbers."""
    if text is None:
        return None
    try:
        if "=" not in text:
            return int(text)
        out = {k: int(v) for k, v in pairs(text, "--top-k", repeat=True).items()}
        if not out:
            raise ValueError(text)
        return out
    except ValueError:  # (an InputError of `pairs` is one too: the same line for every malformed spec)
        raise InputError(f"--top-k: expected N or tool=N,... with whole numbers, got {text!r}") from None
