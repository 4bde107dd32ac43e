"""What the rest of ravenmem may rely on of a memory, and the bound on every search.

`MemoryLike` is the memory's public query surface: the four searches, records, pictures, the
clock and `last_seen`. The reasoning methods, the tools table and the fluent query depend on
this Protocol only, so they run on any object that offers it: the real `ravenmem.Memory`, or
a small one in a test. `check_k` is the one check of a result count, for every front end.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Protocol, runtime_checkable

import numpy as np

from ..errors import InputError
from ..types import Hit, MemoryRecord

if TYPE_CHECKING:
    from ..embed.base import Embedder
    from .places import Whereabouts

MAX_K = 1000  # results per call: beyond this a caller wants an export, not a search
TimeLike = float | int | str | None  # a time expression: Unix seconds or text (ravenmem.timeparse)
Near = tuple[float, float, float]  # a disc of the map: x, y, radius (m)


def check_k(k: object) -> int:
    """k: a whole number from 1 to MAX_K (a bool or a numeric string is refused, not guessed)."""
    if isinstance(k, bool) or not isinstance(k, (int, np.integer)):
        raise InputError(f"k must be a whole number from 1 to {MAX_K}, got {k!r}")
    if not 1 <= int(k) <= MAX_K:
        raise InputError(f"k must be from 1 to {MAX_K}, got {k}")
    return int(k)


@runtime_checkable
class MemoryLike(Protocol):
    """Everything the methods use of a memory: the four searches, records, images and clock.

    `ravenmem.Memory` offers all of it (its methods say what each does) and declares this
    protocol, so the type checker holds its methods to these signatures; `image_file` must
    return only files inside `path` (the agent checks again before it sends a picture)."""

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
    ) -> Whereabouts: ...
