"""Methods by name, for the CLI, the service and the evaluation: `create_method("raven", mem)`.

Every factory takes the memory plus keyword options and ignores options meant for others
(so the evaluator can pass one options dict to every method). VLM-backed methods (`raven`,
`vlm-only`, `caption`) take `vlm` (a `VLMConfig`, a `VLMClient` or None for the
environment/config file) and fail with a one-line `InputError` when no model is configured.
`preset` fills in the options it sets (budget, k per tool, temperature, seed) that are not
given explicitly: explicit options win.
"""

from __future__ import annotations

from typing import Any

from ..errors import InputError
from ..memory.protocol import MemoryLike
from .base import METHODS, Method, needs_vlm, vlm_method
from .client import NO_MODEL
from .config import VLMConfig
from .presets import Preset, apply_preset
from .tool_calls import per_tool_k

AGENT_OPTS = (
    "vlm",
    "top_k",
    "max_tool_calls",
    "trace_path",
    "max_reasks",
    "max_position_offset",
    "image_max_side",
    "show_scores",
    "time_mode",
    "temperature",
    "seed",
    "preset",
)


def _pick(opts: dict[str, Any], names: tuple[str, ...], per_tool: bool = False) -> dict[str, Any]:
    """The options a method takes. Only the VLM agents have one k per tool: the others get the
    text tool's k when a {tool: k} mapping is given."""
    out = {k: v for k, v in opts.items() if k in names and v is not None}
    if not per_tool and isinstance(out.get("top_k"), dict):
        out["top_k"] = per_tool_k(out["top_k"])["search_text"]
    return out


@METHODS.register("raven")
@vlm_method
def _raven(spec: str, memory: MemoryLike, **opts: Any) -> Method:
    from .loop import Agent

    return Agent(memory, **_pick(opts, AGENT_OPTS, per_tool=True))


@METHODS.register("offline")
def _offline(spec: str, memory: MemoryLike, **opts: Any) -> Method:
    from .offline import OfflineReasoner

    return OfflineReasoner(memory, **_pick(opts, ("top_k", "config")))


@METHODS.register("embedder-only")
def _embedder_only(spec: str, memory: MemoryLike, **opts: Any) -> Method:
    from .baselines import EmbedderOnly

    return EmbedderOnly(memory)


@METHODS.register("random")
def _random(spec: str, memory: MemoryLike, **opts: Any) -> Method:
    from .baselines import RandomBaseline

    return RandomBaseline(memory, **_pick(opts, ("seed",)))


@METHODS.register("vlm-only")
@vlm_method
def _vlm_only(spec: str, memory: MemoryLike, **opts: Any) -> Method:
    from .baselines import VLMOnly

    names = ("frames",) + tuple(o for o in AGENT_OPTS if o != "max_tool_calls")
    return VLMOnly(memory, **_pick(opts, names, per_tool=True))


@METHODS.register("caption")
@vlm_method
def _caption(spec: str, memory: MemoryLike, **opts: Any) -> Method:
    from .captions import CaptionAgent

    names = AGENT_OPTS + ("encoder", "captioner", "auto_caption", "segment_frames", "segment_s")
    return CaptionAgent(memory, **_pick(opts, names, per_tool=True))


def create_method(name: str, memory: MemoryLike, preset: str | Preset | None = None, **opts: Any) -> Method:
    """A method by name: raven | offline | embedder-only | vlm-only | caption | random.

    `preset` (raven-qa | navqa | findingdory) supplies the options it sets that `opts` leaves
    out or passes as None; see `ravenmem.agent.presets`."""
    return METHODS.create(name, memory=memory, **apply_preset(preset, opts))


def require_model(name: str, vlm: VLMConfig) -> None:
    """A one-line `InputError` naming how to configure a model, before anything else runs."""
    if not vlm.configured and needs_vlm(name):
        raise InputError(f"method {name!r} needs a VLM: {NO_MODEL}")
