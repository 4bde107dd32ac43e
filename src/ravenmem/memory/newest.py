"""The newest sightings in a time range, found with a few searches, the first ones exact.

`last_seen` keeps asking one question: which memories from time `t` on (maybe inside a disc)
show the thing, i.e. score at least the threshold, and which is the newest? Walking time
windows back from the end took one vector search per window (k = the pool, each reranking
4 k vectors from SQLite): two dozen searches per question at a million memories. And one
search over a wide range is no answer to "the newest": it returns the best matches, which can
all be old (a thing seen far more often, or a little better, before it moved).

1. Only what came after a known sighting can be newer: the caller starts the range there (the
   newest sighting among its best matches), so the range is mostly a short recent stretch.
2. Windows back from the end of the range, by count: the newest `MAX_K` memories the filter
   accepts, then 8 times as many before them, and so on. A window of at most `MAX_K` memories
   is searched exactly (the answer is exact); a wider one is searched for its best `pool`:
   when fewer than that reach the threshold, every sighting in it is in hand; else it is
   searched again after the newest sighting found, each time strictly later. The first window
   that holds a sighting ends the walk. Every search passes the threshold as the store's
   `min_score`: a sighting is all it asks for, so the local store reads from SQLite only the
   vectors whose index codes can reach it, not four times the pool.
3. Later sightings of one place (`Later.find`, inside its disc): one search over the
   whole range (exact when it is short), and nothing found there means nothing (a place is
   mostly not seen again), as the latest mode always decided; else as a wide window above.
   One question's searches are kept and answer its other places inside them (`Later`), as
   does the newest window of step 2 (every sighting from its start on, anywhere:
   `Later.knows`); `Later.find` says whether what it returns is every sighting of the range.
4. Views of a place already in hand are scored by one exact scan of the span and disc that
   hold them (`exact_scores`: vectors only), not by reading each record again, and only when
   they must be: when a place's last search found every later sighting, none of its later
   views shows the thing.

Windows follow the filter's ids (the store's in-RAM columns) and their times, so they tile the
range whatever the order of ids; on a store whose ids follow time each holds the count it says.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from ..store.base import Cameras
from ..types import Filter, Region
from .core import Core
from .places import Sightings
from .protocol import MAX_K

__all__ = ["Later", "cameras_of", "exact_scores", "newest_sightings"]

_GROW = 8  # each window back in time holds this many times more memories than the one before


def newest_sightings(
    mem: Core,
    q: np.ndarray,
    after: float | None,
    before: float | None,
    thr: float,
    *,
    region: Region | None = None,
    pool: int = 200,
    steps: int = 8,
) -> tuple[Sightings, float | None]:
    """Sightings (score >= `thr`) from `after` to `before` inside `region`, from the newest
    window back from the end that holds any (step 2 of the module docstring), and from when
    on they are all there (None when the window's searches ran out first)."""
    ids = mem.store.select(Filter(after=after, before=before, region=region))
    end, size, hi = len(ids), MAX_K, before
    for _ in range(steps):
        if end <= 0:
            break
        start = max(0, end - size)
        lo = after if start == 0 else _time_of(mem, int(ids[start]), after, hi)
        got, complete = _window(mem, q, Filter(after=lo, before=hi, region=region), thr, pool, steps)
        if len(got) or start == 0 or lo == after:
            return got, complete
        end, size, hi = start, size * _GROW, lo
    return Sightings.none(), None


class Later:
    """One question's searches for later sightings of its places (step 3), kept: a place's disc
    is searched a little wider (`margin` m) and, when that search found every sighting in it
    from its start on, a later ask inside that disc and range is answered from it. The rounds
    of one place and places beside each other (one thing seen from several viewpoints) ask
    nearly the same question again and again: each asked the index once before. Asked for the
    places in the order of their last sightings, the first search (the longest range) answers
    the places beside it."""

    def __init__(
        self, mem: Core, q: np.ndarray, thr: float, before: float | None, pool: int, steps: int, margin: float
    ) -> None:
        self.mem, self.q, self.thr, self.before = mem, q, thr, before
        self.pool, self.steps, self.margin = pool, steps, margin
        self.known: list[tuple[float, Region | None, Sightings]] = []  # complete from, disc, sightings

    def knows(self, complete: float, region: Region | None, hits: Sightings) -> None:
        """Every sighting inside `region` (None: anywhere) from `complete` on is among `hits`
        (`newest_sightings`' newest window): a later ask inside them is answered from them."""
        self.known.append((complete, region, hits))

    def find(
        self, after: float, region: Region, keep: Callable[[Sightings], np.ndarray]
    ) -> tuple[Sightings, bool]:
        """Sightings from `after` on inside `region` that pass `keep` (which says it of all of
        them at once), and whether they are all there (a search that found every sighting in
        the range, not its best `pool` of them)."""
        for lo, disc, hits in self.known:
            if lo <= after and (
                disc is None or math.hypot(region.x - disc.x, region.y - disc.y) + region.r <= disc.r
            ):
                return _kept(hits.take((hits.t >= after) & _inside(hits, region)), keep), True
        wide = Region(region.x, region.y, region.r + self.margin)
        filt = Filter(after=after, before=self.before, region=wide)
        hits, complete = _window(self.mem, self.q, filt, self.thr, self.pool, self.steps)
        if complete is not None:
            self.known.append((complete, wide, hits))
        return _kept(hits.take(_inside(hits, region)), keep), complete is not None and complete <= after


def exact_scores(mem: Core, q: np.ndarray, found: Cameras) -> dict[int, float]:
    """Id -> score of memories in hand, from one exact scan of the time span and disc that
    hold them (vectors only: no record is read again); {} when those hold more than `MAX_K`."""
    if not len(found):
        return {}
    x, y = found.poses[:, 0], found.poses[:, 1]
    cx, cy = float(x.mean()), float(y.mean())
    reach = float(np.hypot(x - cx, y - cy).max())
    filt = Filter(
        after=float(found.t.min()), before=float(found.t.max()), region=Region(cx, cy, reach + 1e-3)
    )
    n = mem.store.count(filt)
    if n == 0 or n > MAX_K:
        return {}
    want = set(found.ids.tolist())
    return {i: sc for i, sc in mem.store.search_vector(q, n, filt, exact=True) if i in want}


def cameras_of(mem: Core, ids: list[int]) -> Cameras:
    """The cameras of the stored ones of `ids`, in the order given: from the store's RAM
    (`CameraStore.cameras_of`), else from their records."""
    get = getattr(mem.store, "cameras_of", None)  # optional, as `cameras` is
    return get(ids) if callable(get) else Cameras.of(mem.stored(ids))


def _inside(hits: Sightings, region: Region) -> np.ndarray:
    """The store's disc test (`Filter.region`), per sighting."""
    dx, dy = hits.poses[:, 0] - region.x, hits.poses[:, 1] - region.y
    return dx * dx + dy * dy <= region.r * region.r


def _kept(hits: Sightings, keep: Callable[[Sightings], np.ndarray]) -> Sightings:
    """The sightings `keep` says yes to."""
    return hits.take(keep(hits)) if len(hits) else hits


def _window(
    mem: Core, q: np.ndarray, filt: Filter, thr: float, pool: int, steps: int
) -> tuple[Sightings, float | None]:
    """The sightings of one window: all of them when it is scanned exactly or when a search's
    best `pool` are not all sightings (the rest score lower still); else searched again after
    the newest of those, until that holds. Also from when on the sightings are all there (the
    last search's start; None when the steps ran out first)."""
    out = Sightings.none()
    for _ in range(steps):
        start = filt.after if filt.after is not None else -math.inf
        span = Filter(after=filt.after, before=filt.before)  # its count bounds the filter's
        n = mem.store.count(span if filt.region is not None else filt)
        if n == 0:
            return out, start
        exact = n <= MAX_K
        k = n if exact else min(pool, MAX_K)
        scored = mem.store.search_vector(q, k, filt, exact=exact, min_score=thr)
        hits = _sightings(mem, scored, thr)
        out = out.union(hits)
        if exact or len(scored) < k:
            return out, start
        if not len(hits):  # every one forgotten meanwhile (another process)
            break
        newest = float(hits.t.max())
        if filt.after is not None and newest <= filt.after:
            break
        filt = Filter(after=newest, before=filt.before, region=filt.region)
    return out, None


def _time_of(mem: Core, memory_id: int, lo: float | None, hi: float | None) -> float | None:
    """The time of a stored memory, kept inside [lo, hi] so windows tile the range whatever the
    store's order of ids (`lo` when it was forgotten meanwhile: the window reaches back to it)."""
    got = cameras_of(mem, [memory_id])
    if not len(got):
        return lo
    t = float(got.t[0])
    t = t if hi is None else min(t, hi)
    return t if lo is None else max(t, lo)


def _sightings(mem: Core, scored: list[tuple[int, float]], thr: float) -> Sightings:
    """The scored memories at or above the threshold that are still stored."""
    score = {i: sc for i, sc in scored if sc >= thr}
    if not score:
        return Sightings.none()
    cams = cameras_of(mem, sorted(score))
    return Sightings.of(cams, np.array([score[i] for i in cams.ids.tolist()], np.float64))
