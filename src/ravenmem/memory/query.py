"""A fluent query: `mem.query().after("10 minutes ago").near(x, y, 3).text("red mug").limit(5).run()`.

A `Query` is immutable: every step returns a new query, so a base query can be kept and
refined in several directions (`base = mem.query().after("+60")`, then `base.text("mug")` and
`base.position(1, 2)`) without one refinement leaking into another. Arguments are checked when
the query runs, by the `Memory` method it calls (one place for every front end).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import cast

import numpy as np

from ..errors import InputError
from ..types import Hit
from .protocol import MemoryLike, TimeLike, check_k


@dataclass(frozen=True)
class Query:
    """Filters and at most one retrieval mode; `run()` calls the matching tool."""

    memory: MemoryLike
    after_t: TimeLike = None
    before_t: TimeLike = None
    disc: tuple[float, float, float] | None = None
    k: int = 5
    mode: tuple[str, object] | None = None

    def after(self, t: TimeLike) -> Query:
        return replace(self, after_t=t)

    def before(self, t: TimeLike) -> Query:
        return replace(self, before_t=t)

    def near(self, x: float, y: float, r: float) -> Query:
        return replace(self, disc=(x, y, r))

    def limit(self, k: int) -> Query:
        return replace(self, k=check_k(k))

    def _set(self, mode: str, arg: object) -> Query:
        if self.mode is not None:
            raise InputError(f"a query has one mode; {self.mode[0]!r} is already set")
        return replace(self, mode=(mode, arg))

    def text(self, q: str) -> Query:
        return self._set("text", q)

    def image(self, img: np.ndarray | str) -> Query:
        return self._set("image", img)

    def time(self, t: TimeLike) -> Query:
        return self._set("time", t)

    def position(self, x: float, y: float, z: float | None = None) -> Query:
        return self._set("position", (x, y, z))

    def run(self) -> list[Hit]:
        m, k, a, b, near = self.memory, self.k, self.after_t, self.before_t, self.disc
        if self.mode is None:  # only filters: chronological from the window's start
            return m.search_time(a if a is not None else "start", k, after=a, before=b, near=near)
        mode, arg = self.mode
        if mode == "text":
            return m.search_text(cast(str, arg), k, after=a, before=b, near=near)
        if mode == "image":
            return m.search_image(arg, k, after=a, before=b, near=near)  # type: ignore[arg-type]
        if mode == "time":
            return m.search_time(arg, k, after=a, before=b, near=near)  # type: ignore[arg-type]
        x, y, z = cast(tuple[float, float, "float | None"], arg)
        return m.search_position(x, y, z, k, radius=near[2] if near else None, after=a, before=b)

    __call__ = run
