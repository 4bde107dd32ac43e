"""Diverse results: no two hits from the same moment and place.

A dense memory (every frame kept, or a robot that stood still) holds many near-identical views
taken fractions of a second apart; ranked by similarity they fill the whole top-k with one view.
Two memories are *the same view* when they were taken within `seconds` of each other AND within
`metres` AND their headings differ by at most `degrees` (full 3-D angle when both poses have a
quaternion, else yaw). Each of the three alone is not enough: the same place at another time may
show something new (time questions need it), and a camera turning on the spot sees new things
within a second.

`pick` keeps hits in rank order and drops a hit that is the same view as one already kept;
`top_hits` asks the ranking for more candidates until k diverse hits are found or there are no
more. The text and image tools use this by default (`diverse=False` turns it off).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass

from ..types import Hit, MemoryRecord

FETCH_FACTOR = 4  # candidates asked for per diverse hit wanted, growing by this factor when short


@dataclass(frozen=True)
class SameView:
    """When two memories count as the same moment and place (see the module docstring)."""

    seconds: float = 2.0
    metres: float = 0.5
    degrees: float = 30.0

    def __call__(self, a: MemoryRecord, b: MemoryRecord) -> bool:
        return (
            abs(a.t - b.t) <= self.seconds
            and a.pose.distance_to(b.pose) <= self.metres
            and a.pose.rotation_to(b.pose) <= math.radians(self.degrees)
        )


SAME_VIEW = SameView()


def pick(hits: Sequence[Hit], k: int, same: SameView = SAME_VIEW) -> list[Hit]:
    """The first k hits (in the given order) of which no two are the same view."""
    kept: list[Hit] = []
    for h in hits:
        if len(kept) >= k:
            break
        if not any(same(h.memory, o.memory) for o in kept):
            kept.append(h)
    return kept


def top_hits(
    ranked: Callable[[int], list[Hit]], k: int, diverse: bool, total: int, same: SameView = SAME_VIEW
) -> list[Hit]:
    """k hits from `ranked(n)` (the best n, best first); diverse ones unless `diverse` is False.

    Asks for FETCH_FACTOR * k candidates, then FETCH_FACTOR times more while fewer than k diverse
    hits were found and the memory (`total` memories) may hold more.
    """
    if not diverse or k <= 1:
        return ranked(k)[:k]
    n = max(k, 1) * FETCH_FACTOR
    while True:
        cands = ranked(n)
        hits = pick(cands, k, same)
        if len(hits) >= k or len(cands) < n or n >= total:
            return hits
        n *= FETCH_FACTOR
