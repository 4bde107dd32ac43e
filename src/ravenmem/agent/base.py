"""What a reasoning method is, and the registry the evaluator and the front ends find them in.

Methods depend only on the memory's public query surface (`ravenmem.memory.MemoryLike`), so
they run on any object that offers it: the real `ravenmem.Memory`, or a small one in a test.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, Protocol, TypeVar, runtime_checkable

import numpy as np

from ..registry import Registry
from .schema import Answer


@runtime_checkable
class Method(Protocol):
    """A way of answering questions from a memory; all return the same `Answer` schema."""

    name: str

    def ask(self, question: str, image: np.ndarray | None = None) -> Answer: ...


METHODS: Registry[Method] = Registry(
    "method",
    "ravenmem.methods",
    dict.fromkeys(
        ("raven", "offline", "embedder-only", "random", "vlm-only", "caption"), "ravenmem.agent.methods"
    ),
)

F = TypeVar("F", bound=Callable[..., Any])


def vlm_method(factory: F) -> F:
    """Mark a method factory as one that cannot answer without a VLM. The evaluator refuses to
    run such a method when no model is configured (instead of a silent stand-in); third-party
    factories registered by entry point can carry the same `needs_vlm = True` attribute."""
    factory.needs_vlm = True  # type: ignore[attr-defined]
    return factory


def needs_vlm(name: str) -> bool:
    """Whether the method registered as `name` needs a VLM (imports only its registering module)."""
    return bool(getattr(METHODS.get(name), "needs_vlm", False))
