"""Per-benchmark agent settings, in one place: tool-call budget, top-k per tool, temperature, seed.

    from ravenmem.agent import create_method
    agent = create_method("raven", mem, preset="findingdory")          # 15 calls, time k=200, ...
    agent = create_method("raven", mem, preset="navqa", top_k=8)        # explicit options win

Budgets and k follow the RAVEN paper: 3 tool calls and k=5 per tool for RAVEN-QA and NaVQA; 15
calls for FindingDory, whose questions span whole episodes, with k=200 for the time tool, 30 for
the text tool and 1 for the position tool (5 for the image tool). The paper's temperature and
seed could not be found in any source available to us, so every preset uses temperature 0 and
seed 0 (greedy and repeatable where the server honours a seed); see docs/agent.md.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

from ..errors import InputError


@dataclass(frozen=True)
class Preset:
    name: str
    max_tool_calls: int
    top_k: Mapping[str, int]
    temperature: float = 0.0
    seed: int = 0
    about: str = ""

    def options(self) -> dict[str, Any]:
        """The method options this preset sets (`create_method` merges them under explicit ones)."""
        return {
            "max_tool_calls": self.max_tool_calls,
            "top_k": dict(self.top_k),
            "temperature": self.temperature,
            "seed": self.seed,
        }


PRESETS: dict[str, Preset] = {
    p.name: p
    for p in (
        Preset(
            "raven-qa",
            3,
            {"text": 5, "image": 5, "time": 5, "position": 5},
            about="RAVEN-QA: 3 tool calls, 5 memories per call",
        ),
        Preset(
            "navqa",
            3,
            {"text": 5, "image": 5, "time": 5, "position": 5},
            about="NaVQA: 3 tool calls, 5 memories per call",
        ),
        Preset(
            "findingdory",
            15,
            {"text": 30, "image": 5, "time": 200, "position": 1},
            about="FindingDory: 15 tool calls; time 200, text 30, image 5, position 1 memories per call",
        ),
    )
}


def get_preset(name: str | Preset | None) -> Preset | None:
    if name is None or isinstance(name, Preset):
        return name
    preset = PRESETS.get(name)
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
        out: dict[str, int] = {}
        for part in text.split(","):
            if not part.strip():
                continue
            key, sep, val = part.partition("=")
            if not sep or not key.strip():
                raise ValueError(part)
            out[key.strip()] = int(val)
        if not out:
            raise ValueError(text)
        return out
    except ValueError:
        raise InputError(f"--top-k: expected N or tool=N,... with whole numbers, got {text!r}") from None
