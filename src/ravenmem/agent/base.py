"""What every reasoning method needs from a memory, and what it must offer the evaluator.

Methods depend only on the Memory's public query surface (this Protocol), so they run on any
object that offers it: the real `ravenmem.Memory`, or a small one in a test.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any, Protocol, TypeVar, runtime_checkable

import numpy as np

from ..registry import Registry
from ..types import Hit, MemoryRecord
from .schema import Answer

TimeLike = float | int | str | None
Near = tuple[float, float, float]


@runtime_checkable
class MemoryLike(Protocol):
    path: Path

    def search_text(
        self,
        query: str,
        k: int = 5,
        after: TimeLike = None,
        before: TimeLike = None,
        near: Near | None = None,
    ) -> list[Hit]: ...

    def search_image(
        self,
        image: np.ndarray | str | os.PathLike[str] | None = None,
        k: int = 5,
        after: TimeLike = None,
        before: TimeLike = None,
        near: Near | None = None,
        memory_id: int | None = None,
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

    def load_image(self, rec: MemoryRecord) -> np.ndarray | None: ...

    def count(self) -> int: ...

    def time_span(self) -> tuple[float, float]: ...

    def parse_time(self, expr: TimeLike) -> float: ...


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


def image_file(mem: Any, rec: MemoryRecord) -> Path | None:
    """The memory's image file when the memory can say where it is (sent byte for byte)."""
    fn = getattr(mem, "image_file", None)
    if fn is not None:
        p = fn(rec)
        return Path(p) if p is not None else None
    if rec.image_path:
        p = Path(rec.image_path)
        p = p if p.is_absolute() else Path(mem.path) / p
        return p if p.exists() else None
    return None


def record_image_url(mem: Any, rec: MemoryRecord, max_side: int = 0) -> str | None:
    """A memory's image as a data URL (its JPEG file as is when possible), None if it has none."""
    from .client import image_data_url

    p = image_file(mem, rec)
    if p is not None:
        try:
            return image_data_url(p, max_side)
        except OSError:
            pass
    arr = mem.load_image(rec)
    return image_data_url(arr, max_side) if arr is not None else None


def all_records(mem: Any) -> list[MemoryRecord]:
    """Every memory, chronological: `all_records()` when offered, else the time tool from the start."""
    fn = getattr(mem, "all_records", None)
    if fn is not None:
        return list(fn())
    n = mem.count()
    if n == 0:
        return []
    t0, _ = mem.time_span()
    return [h.memory for h in mem.search_time(t0, k=n)]
