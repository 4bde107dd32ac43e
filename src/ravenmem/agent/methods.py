"""Methods by name, for the CLI, the service and the evaluation, built from one `MethodOptions`.

Each factory takes the memory and the typed options (`ravenmem.agent.ask.MethodOptions`, the
preset already filled in, once); the VLM agents take them as they are (`Agent(memory,
options)`), the others read the fields they use; a field left None keeps the method's own
default. VLM-backed methods (`raven`, `vlm-only`, `caption`) take `options.vlm` (a
`VLMConfig`, a `VLMClient`, or None for the environment and config file) and fail with a
one-line `InputError` when no model is configured. A plugin registered under
`ravenmem.methods` is called the same way: `factory(spec, memory=..., options=...)`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from ..errors import InputError
from ..memory.protocol import MemoryLike
from .ask import create_method
from .base import METHODS, Method, needs_vlm, vlm_method
from .client import NO_MODEL
from .config import VLMConfig
from .tool_calls import per_tool_k

if TYPE_CHECKING:
    from .ask import MethodOptions

__all__ = ["create_method", "require_model"]


def _given(**values: Any) -> dict[str, Any]:
    """The keyword arguments that were set: None leaves the constructor's default."""
    return {k: v for k, v in values.items() if v is not None}


def _text_k(top_k: int | dict[str, int] | None) -> int | None:
    """Methods with one k take the text tool's k of a {tool: k} mapping."""
    return per_tool_k(top_k)["search_text"] if isinstance(top_k, dict) else top_k


@METHODS.register("raven")
@vlm_method
def _raven(spec: str, memory: MemoryLike, options: MethodOptions) -> Method:
    from .loop import Agent

    return Agent(memory, options)


@METHODS.register("offline")
def _offline(spec: str, memory: MemoryLike, options: MethodOptions) -> Method:
    from .offline import OfflineReasoner

    return OfflineReasoner(memory, **_given(top_k=_text_k(options.top_k), config=options.offline_config))


@METHODS.register("embedder-only")
def _embedder_only(spec: str, memory: MemoryLike, options: MethodOptions) -> Method:
    from .baselines import EmbedderOnly

    return EmbedderOnly(memory)


@METHODS.register("random")
def _random(spec: str, memory: MemoryLike, options: MethodOptions) -> Method:
    from .baselines import RandomBaseline

    return RandomBaseline(memory, **_given(seed=options.seed))


@METHODS.register("vlm-only")
@vlm_method
def _vlm_only(spec: str, memory: MemoryLike, options: MethodOptions) -> Method:
    from .baselines import VLMOnly

    return VLMOnly(memory, options)


@METHODS.register("caption")
@vlm_method
def _caption(spec: str, memory: MemoryLike, options: MethodOptions) -> Method:
    from .captions import CaptionAgent

    return CaptionAgent(memory, options)


def require_model(name: str, vlm: VLMConfig) -> None:
    """A one-line `InputError` naming how to configure a model, before anything else runs."""
    if not vlm.configured and needs_vlm(name):
        raise InputError(f"method {name!r} needs a VLM: {NO_MODEL}")
