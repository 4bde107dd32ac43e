"""Methods by name, for the CLI and the evaluation: `create_method("offline", mem)`.

Every factory takes the memory plus keyword options and ignores options meant for others
(so the evaluator can pass one options dict to every method). VLM-backed methods take `vlm`
(a `VLMConfig`, a `VLMClient` or None for the environment/config file).
"""

from __future__ import annotations

from typing import Any

from .base import METHODS, MemoryLike, Method, vlm_method
from .tools import per_tool_k

_AGENT_OPTS = (
    "vlm",
    "top_k",
    "max_tool_calls",
    "trace_path",
    "max_reasks",
    "max_position_offset",
    "image_max_side",
)


def _pick(opts: dict[str, Any], names: tuple[str, ...], per_tool: bool = False) -> dict[str, Any]:
    """The options a method takes. Only the VLM agent has one k per tool: the others get the
    text tool's k when a {tool: k} mapping is given."""
    out = {k: v for k, v in opts.items() if k in names and v is not None}
    if not per_tool and isinstance(out.get("top_k"), dict):
        out["top_k"] = per_tool_k(out["top_k"])["search_text"]
    return out


@METHODS.register("raven")
@vlm_method
def _raven(spec: str, memory: MemoryLike, **opts: Any) -> Method:
    from .loop import Agent

    return Agent(memory, **_pick(opts, _AGENT_OPTS, per_tool=True))


@METHODS.register("offline")
def _offline(spec: str, memory: MemoryLike, **opts: Any) -> Method:
    from .offline import OfflineReasoner

    return OfflineReasoner(memory, **_pick(opts, ("top_k", "settings")))


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

    extra = ("frames",) + tuple(o for o in _AGENT_OPTS if o != "max_tool_calls")
    return VLMOnly(memory, **_pick(opts, extra))


@METHODS.register("caption")
@vlm_method
def _caption(spec: str, memory: MemoryLike, **opts: Any) -> Method:
    from .captions import CaptionAgent

    return CaptionAgent(memory, **_pick(opts, _AGENT_OPTS + ("encoder", "captioner", "auto_caption")))


def create_method(name: str, memory: MemoryLike, **opts: Any) -> Method:
    """A method by name: raven | offline | embedder-only | vlm-only | caption | random."""
    return METHODS.create(name, memory=memory, **opts)
