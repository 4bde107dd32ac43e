"""What every reasoning method needs from a memory, and what it must offer the evaluator.

Methods depend only on the Memory's public query surface (this Protocol), so they run on any
object that offers it: the real `ravenmem.Memory`, or a small one in a test.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, Protocol, TypeVar, runtime_checkable

import numpy as np

from ..embed.base import Embedder
from ..registry import Registry
from ..types import Hit, MemoryRecord
from .schema import Answer

if TYPE_CHECKING:
    from ..changes import ChangeSettings, Whereabouts

TimeLike = float | int | str | None
Near = tuple[float, float, float]


@runtime_checkable
class MemoryLike(Protocol):
    """Everything the methods use of a memory: the four searches, records, images and clock.

    `ravenmem.Memory` offers all of it; `image_file` must return only files inside `path`
    (the agent checks again before it sends a picture)."""

    path: Path

    @property
    def embedder(self) -> Embedder: ...

    @property
    def ocr_enabled(self) -> bool: ...

    def search_text(
        self,
        query: str,
        k: int = 5,
        after: TimeLike = None,
        before: TimeLike = None,
        near: Near | None = None,
        diverse: bool = True,
    ) -> list[Hit]: ...

    def search_texts(
        self,
        queries: Sequence[str],
        k: int = 5,
        after: TimeLike = None,
        before: TimeLike = None,
        near: Near | None = None,
        ocr: bool = True,
        diverse: bool = True,
    ) -> list[list[Hit]]: ...

    def search_image(
        self,
        image: np.ndarray | str | os.PathLike[str] | None = None,
        k: int = 5,
        after: TimeLike = None,
        before: TimeLike = None,
        near: Near | None = None,
        memory_id: int | None = None,
        diverse: bool = True,
    ) -> list[Hit]: ...

    def search_time(
        self,
        t: TimeLike,
        k: int = 5,
        after: TimeLike = None,
        before: TimeLike = None,
        near: Near | None = None,
        centred: bool = False,
    ) -> list[Hit]: ...

    def search_position(
        self,
        x: float,
        y: float,
        z: float | None = None,
        k: int = 5,
        radius: float | None = None,
        after: TimeLike = None,
        before: TimeLike = None,
    ) -> list[Hit]: ...

    def get(self, ids: Sequence[int]) -> list[MemoryRecord]: ...

    def all_records(self) -> list[MemoryRecord]: ...

    def image_file(self, rec: MemoryRecord) -> Path | None: ...

    def load_image(self, rec: MemoryRecord) -> np.ndarray | None: ...

    def count(self) -> int: ...

    def time_span(self) -> tuple[float, float]: ...

    def parse_time(self, expr: TimeLike) -> float: ...

    def last_seen(
        self,
        query: str | None = None,
        *,
        image: np.ndarray | str | os.PathLike[str] | None = None,
        memory_id: int | None = None,
        vector: np.ndarray | None = None,
        after: TimeLike = None,
        before: TimeLike = None,
        near: Near | None = None,
        min_score: float | None = None,
        settings: ChangeSettings | None = None,
    ) -> Whereabouts: ...


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
