"""A fluent query: `mem.query().after("10 minutes ago").near(x, y, 3).text("red mug").limit(5).run()`."""

from __future__ import annotations

from typing import TYPE_CHECKING, cast

import numpy as np

from .errors import InputError
from .types import Hit

if TYPE_CHECKING:
    from .memory import Memory, TimeLike


class Query:
    """Collects filters and one retrieval mode, then runs the matching tool on `run()`."""

    def __init__(self, memory: Memory) -> None:
        self._mem = memory
        self._after: TimeLike = None
        self._before: TimeLike = None
        self._near: tuple[float, float, float] | None = None
        self._k = 5
        self._mode: tuple[str, object] | None = None

    def after(self, t: TimeLike) -> Query:
        self._after = t
        return self

    def before(self, t: TimeLike) -> Query:
        self._before = t
        return self

    def near(self, x: float, y: float, r: float) -> Query:
        self._near = (x, y, r)
        return self

    def limit(self, k: int) -> Query:
        if k < 1:
            raise InputError(f"limit must be >= 1, got {k}")
        self._k = k
        return self

    def _set(self, mode: str, arg: object) -> Query:
        if self._mode is not None:
            raise InputError(f"a query has one mode; {self._mode[0]!r} is already set")
        self._mode = (mode, arg)
        return self

    def text(self, q: str) -> Query:
        return self._set("text", q)

    def image(self, img: np.ndarray | str) -> Query:
        return self._set("image", img)

    def time(self, t: TimeLike) -> Query:
        return self._set("time", t)

    def position(self, x: float, y: float, z: float | None = None) -> Query:
        return self._set("position", (x, y, z))

    def run(self) -> list[Hit]:
        m, k, a, b = self._mem, self._k, self._after, self._before
        if self._mode is None:  # only filters: chronological from the window's start
            return m.search_time(a if a is not None else "start", k, after=a, before=b, near=self._near)
        mode, arg = self._mode
        if mode == "text":
            return m.search_text(str(arg), k, after=a, before=b, near=self._near)
        if mode == "image":
            return m.search_image(arg, k, after=a, before=b, near=self._near)  # type: ignore[arg-type]
        if mode == "time":
            return m.search_time(arg, k, after=a, before=b, near=self._near)  # type: ignore[arg-type]
        x, y, z = cast(tuple[float, float, "float | None"], arg)
        radius = self._near[2] if self._near else None
        hits = m.search_position(x, y, z, k, radius=radius, after=a, before=b)
        return hits

    __call__ = run
