"""Views and places: which memories look at the same scene, how sightings group into places,
and what the robot's later visits of a place show (steps 2 and 3 of `ravenmem.memory.changes`).

`ChangeConfig` holds every rule's numbers; `overlaps` is the one test of two views.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from ..errors import InputError
from ..store.base import Cameras
from ..types import Filter, Hit, MemoryRecord, Region
from .core import Core
from .newest import Later, exact_scores
from .places import Place, Sightings, among, read_rows
from .protocol import MAX_K

_PAGE = 256  # memories read per step of a walk forward in time, at most


@dataclass(frozen=True)
class ChangeConfig:
    """How sightings, places and revisits are decided. `match_ratio`: a memory shows the thing
    when its score is at least floor + match_ratio * (best - floor). `view_radius` (m) and
    `view_angle_deg`: two views overlap when their cameras are this close and turned this
    little from each other. `episode_gap_s`: sightings further apart than this are different
    passes (None: 30 times the memory's mean time between keyframes while recording). `pool`: candidates
    read per search (at most 1000)."""

    pool: int = 200
    match_ratio: float = 0.5
    view_radius: float = 1.5
    view_angle_deg: float = 45.0
    episode_gap_s: float | None = None
    floor_sample: int = 64
    recency_windows: int = 8
    max_rounds: int = 8
    max_walk: int = 2000
    max_revisits: int = 5

    def __post_init__(self) -> None:
        if not 1 <= self.pool <= MAX_K or not 0.0 < self.match_ratio < 1.0:
            raise InputError(f"changes: pool must be 1..{MAX_K} and 0 < match_ratio < 1: {self}")
        if self.view_radius <= 0 or not 0 < self.view_angle_deg <= 180 or self.max_revisits < 1:
            raise InputError(
                f"changes: view_radius > 0, 0 < view_angle_deg <= 180, max_revisits >= 1: {self}"
            )
        if self.episode_gap_s is not None and not self.episode_gap_s > 0:
            raise InputError(f"changes: episode_gap_s must be > 0 (or None), got {self.episode_gap_s}")


def _scores(mem: Core, q: np.ndarray, found: Cameras) -> tuple[Cameras, np.ndarray]:
    """The memories of `found` still stored, with their scores: from one exact scan
    (`exact_scores`), else from each one's embedding."""
    got = exact_scores(mem, q, found)
    rest = [int(i) for i in found.ids if int(i) not in got]
    for r in sample(mem, rest, embeddings=True) if rest else []:
        assert r.embedding is not None
        got[r.id] = float(np.dot(r.embedding, q))
    kept = found.take(np.array([int(i) in got for i in found.ids], bool).reshape(-1))
    return kept, np.array([got[int(i)] for i in kept.ids], np.float64)


def cameras(mem: Core, t: float, k: int, filt: Filter) -> Cameras:
    """`by_time`'s memories as cameras: from the store's RAM when it keeps them
    (`CameraStore`), else from their records."""
    if _has_cameras(mem):
        return mem.store.cameras(t, k, filt)  # type: ignore[attr-defined]
    return Cameras.of(mem.store.by_time(t, k, filt))


def _has_cameras(mem: Core) -> bool:
    """Whether the store answers `cameras` (`store.base.CameraStore`; the method looked up:
    `isinstance` on a protocol costs more than the call it guards)."""
    return callable(getattr(mem.store, "cameras", None))


def _after(found: Cameras, mark: tuple[float, int]) -> np.ndarray:
    """Which of `found` come after `mark` in (time, id) order."""
    return (found.t > mark[0]) | ((found.t == mark[0]) & (found.ids > mark[1]))


def sample(mem: Core, ids: Sequence[int], embeddings: bool = False) -> list[MemoryRecord]:
    """The records of `ids` that exist (ids a forget removed are skipped)."""
    return mem.stored(ids, with_embeddings=embeddings)


def overlaps(a: MemoryRecord, b: MemoryRecord, s: ChangeConfig | None = None) -> bool:
    """Whether two memories look at the same scene: cameras within `view_radius` (in the plane)
    and turned at most `view_angle_deg` from each other."""
    return overlap_rows(_row(a), _row(b), s or ChangeConfig())


def overlap_rows(a: Sequence[float], b: Sequence[float], s: ChangeConfig) -> bool:
    """`overlaps` for two cameras as rows of `_poses` (x, y, yaw, quaternion; NaN: none): the
    same arithmetic as `Pose.rotation_to`."""
    if not math.hypot(a[0] - b[0], a[1] - b[1]) <= s.view_radius:
        return False
    if not (math.isnan(a[3]) or math.isnan(b[3])):  # both have a quaternion
        turn = 2.0 * math.acos(min(1.0, abs(a[3] * b[3] + a[4] * b[4] + a[5] * b[5] + a[6] * b[6])))
    else:
        turn = abs((b[2] - a[2] + math.pi) % (2.0 * math.pi) - math.pi)
    return math.degrees(turn) <= s.view_angle_deg


def _row(r: MemoryRecord) -> list[float]:
    """A record's camera as a row of `_poses`."""
    p, nan = r.pose, math.nan
    return [p.x, p.y, p.yaw, *(p.quat or (nan, nan, nan, nan))]


def overlapping(recs: Sequence[MemoryRecord], cams: Sequence[MemoryRecord], s: ChangeConfig) -> np.ndarray:
    """Per record, whether its view overlaps one of `cams` (`overlaps`, the same arithmetic in
    the same order, over all pairs at once: a page of records against a place's hundreds of
    sightings was that many calls)."""
    if not recs or not cams:
        return np.zeros(len(recs), bool)
    return overlapping_poses(_poses(recs), _poses(cams), s)


def overlapping_poses(a: np.ndarray, b: np.ndarray, s: ChangeConfig) -> np.ndarray:
    """`overlapping` for poses as `_poses` gives them ((n, 7) arrays, e.g. `Cameras.poses`)."""
    out = np.zeros(len(a), bool)
    if not len(a) or not len(b):
        return out
    close = np.hypot(a[:, 0, None] - b[:, 0], a[:, 1, None] - b[:, 1]) <= s.view_radius
    i, j = np.nonzero(close)  # turns only for the pairs close enough (mostly a few)
    if not len(i):
        return out
    turn = np.abs(np.mod(b[j, 2] - a[i, 2] + math.pi, 2.0 * math.pi) - math.pi)
    has_a, has_b = ~np.isnan(a[:, 3]), ~np.isnan(b[:, 3])  # a quaternion: four numbers or none
    if has_a.any() and has_b.any():  # the 3-D turn where both poses carry one
        both = has_a[i] & has_b[j]
        qa, qb, i2, j2 = a[:, 3:].T, b[:, 3:].T, i[both], j[both]
        dot = np.abs(
            qa[0][i2] * qb[0][j2] + qa[1][i2] * qb[1][j2] + qa[2][i2] * qb[2][j2] + qa[3][i2] * qb[3][j2]
        )
        turn[both] = 2.0 * np.arccos(np.minimum(1.0, dot))
    out[i[np.degrees(turn) <= s.view_angle_deg]] = True
    return out


def _poses(recs: Sequence[MemoryRecord]) -> np.ndarray:
    """(n, 7): x, y, yaw and the quaternion (NaN without one) of each record's pose."""
    return Cameras.of(recs).poses


def group_sightings(mem: Core, seen: Sightings, s: ChangeConfig) -> list[np.ndarray]:
    """Places, as rows of `seen` (chronological): each sighting joins the best-scored earlier
    seed whose view it overlaps (no chains: a robot turning on the spot does not make one place
    of every direction), and sightings that follow each other in time with no memory in between
    are one place (the robot kept the thing in view while it moved). Seeds are taken best
    first, each claiming at once every lower-scored sighting left that overlaps it: one pass
    per seed (a few), not one test per sighting and seed."""
    n = len(seen)
    seed_of = np.arange(n)
    left = np.argsort(-seen.scores, kind="stable")
    seeds: list[int] = []
    while len(left):
        seed, rest = int(left[0]), left[1:]
        seeds.append(seed)
        claimed = overlapping_poses(seen.poses[rest], seen.poses[seed : seed + 1], s)
        seed_of[rest[claimed]] = seed
        left = rest[~claimed]
    parent = {sd: sd for sd in seeds}

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    ids, t = seen.ids.tolist(), seen.t.tolist()
    apart = _apart(mem, ids)
    for i in np.flatnonzero((seed_of[:-1] != seed_of[1:]) & ~apart).tolist():
        a, b = root(int(seed_of[i])), root(int(seed_of[i + 1]))
        if a != b and next_in_time(mem, (t[i], ids[i]), (t[i + 1], ids[i + 1])):
            parent[a] = b
    lut = np.zeros(n, np.int64)
    for sd in seeds:
        lut[sd] = root(sd)
    place = lut[seed_of]
    _, first = np.unique(place, return_index=True)
    return [np.flatnonzero(place == place[i]) for i in np.sort(first)]


def _apart(mem: Core, ids: list[int]) -> np.ndarray:
    """Per pair of sightings in a row (their ids, chronological), whether a memory surely lies
    between them: their places in time order (`time_order`, one call for all) are not next to
    each other. The pairs left are asked `next_in_time` one by one (a pool's sightings are
    mostly days apart: sixty store calls per question were spent finding that out)."""
    time_order = getattr(mem.store, "time_order", None)  # optional, as `cameras` is
    order = time_order(ids) if callable(time_order) else None
    if order is None or len(ids) < 2:
        return np.zeros(max(0, len(ids) - 1), bool)
    return (order[1:] != order[:-1] + 1) | (order[:-1] < 0)


def next_in_time(mem: Core, a: tuple[float, int], b: tuple[float, int]) -> bool:
    """Whether memories `a` and `b` ((time, id) each) are, in (time, id) order, the first two
    memories of the time span [a's, b's], both stored: a store that keeps cameras in RAM
    answers from those two; otherwise it is counted from the ids in the span (the store's
    filter, no record read), not counting those at `b`'s time with a larger id (after `b` in
    that order)."""
    (at, a_id), (bt, b_id) = a, b
    if _has_cameras(mem):
        return mem.store.cameras(at, 2, Filter(before=bt)).ids.tolist() == [a_id, b_id]  # type: ignore[attr-defined]
    ids = mem.store.select(Filter(after=at, before=bt))  # sorted
    if len(ids) < 2:
        return False
    if len(ids) > 2:
        tied = mem.store.select(Filter(after=bt, before=bt))
        if len(ids) - 2 - int((tied > b_id).sum()) != 0:
            return False
    pos = np.searchsorted(ids, [a_id, b_id])
    return bool(np.all(pos < len(ids)) and np.all(ids[np.minimum(pos, len(ids) - 1)] == [a_id, b_id]))


def _disc(p: Place, s: ChangeConfig) -> tuple[Region, np.ndarray]:
    """The cameras a later view is compared with (the last 16 sightings and the best one, as
    `_poses` gives them), and a disc around them that holds every camera overlapping one."""
    poses, best = p.found.poses, p.best_row
    lo = max(0, len(poses) - 16)
    poses = poses[lo:] if best >= lo else np.concatenate([poses[lo:], poses[best : best + 1]])
    x, y = poses[:, 0], poses[:, 1]
    cx, cy = float(x.sum()) / len(x), float(y.sum()) / len(y)  # the mean, without its overhead
    reach = float(np.hypot(x - cx, y - cy).max())
    return Region(cx, cy, reach + s.view_radius), poses


def _views(
    mem: Core, q: np.ndarray, found: Cameras, cams: np.ndarray, s: ChangeConfig, thr: float, known: bool
) -> Cameras:
    """The memories of `found` whose view overlaps one of `cams` (poses as `_poses` gives them)
    and that do not show the thing (score below `thr`), in `found`'s order. `known`: every
    later sighting of the place is in hand (`grow`), so no later view of it shows the thing
    and none is scored."""
    near = found.take(overlapping_poses(found.poses, cams, s))
    if known or not len(near):
        return near
    kept, scores = _scores(mem, q, near)
    return kept.take(scores < thr)


def _later_sightings(p: Place, s: ChangeConfig, later: Later) -> tuple[Sightings, bool]:
    """Every later view of the place, inside its disc, that shows the thing (up to the newest),
    and whether that is all of them (`Later.find`)."""
    disc, poses = _disc(p, s)
    last = p.found.key(-1)

    def later_views(found: Sightings) -> np.ndarray:
        return _after(found.cameras, last) & overlapping_poses(found.poses, poses, s)

    return later.find(last[0], disc, later_views)


def _newest_view(
    mem: Core,
    q: np.ndarray,
    p: Place,
    disc: Region,
    poses: np.ndarray,
    s: ChangeConfig,
    asof: Filter,
    thr: float,
    known: bool,
) -> int | None:
    """The newest view of the place after its last sighting that does not show the thing (as
    `_views` decides it): time windows growing backwards from the end, inside the place's
    disc (`_disc`: `disc`, `poses`)."""
    last = p.found.key(-1)
    lo = last[0]
    hi = asof.before if asof.before is not None else mem.time_span()[1]
    width = max((hi - lo) / 64.0, 1e-3)
    for _ in range(s.recency_windows + 4):
        start = max(lo, hi - width)
        found = cameras(mem, start, s.pool, Filter(after=start, before=hi, region=disc))
        found = found.take(_after(found, last))
        if known:  # the last camera that overlaps: the newest few tested first
            for rows in (np.arange(max(0, len(found) - 4), len(found)), np.arange(max(0, len(found) - 4))):
                hit = rows[overlapping_poses(found.poses[rows], poses, s)]
                if len(hit):
                    return int(found.ids[hit[-1]])
        else:
            got = _views(mem, q, found, poses, s, thr, known)
            if len(got):
                return int(got.ids[-1])
        if start <= lo:
            return None
        width *= 4.0
    return None


def grow(p: Place, s: ChangeConfig, later: Later) -> bool:
    """Add the place's later sightings (its own views after its last sighting that show the
    thing), round by round until none is new. Returns whether they are all in hand: the last
    round's search found every sighting from the place's last one on (`Later.find`)."""
    for _ in range(s.max_rounds):
        more, complete = _later_sightings(p, s, later)
        if not len(more):
            return complete
        p.found = p.found.union(more)
    return False


def revisits(
    mem: Core,
    p: Place,
    q: np.ndarray,
    thr: float,
    s: ChangeConfig,
    asof: Filter,
    gap: float,
    known: bool = False,
) -> list[int]:
    """The later views of the place without the thing (`revisit_count`; returns the ids of
    those kept for `Place.revisits`, see `read_revisits`) and whether the robot came back to
    it at all (`later_visit`): decided on cameras (poses, and scores unless `known`: every
    later sighting of the place is in hand, see `grow`)."""
    views, last = p.found.poses, p.found.key(-1)
    end = _visit_end(mem, views, last, s, asof, views[-16:])
    start = last[0] + gap if end is None else max(end, last[0] + gap)
    disc, poses = _disc(p, s)
    first = cameras(mem, start, s.pool, Filter(before=asof.before, region=disc))
    without = _views(mem, q, first, poses, s, thr, known).ids.tolist()
    count = len(without)
    if without:
        newest = _newest_view(mem, q, p, disc, poses, s, asof, thr, known)
        if newest is not None and newest not in set(without):
            without.append(newest)
            count = max(count + 1, len(without))
    keep = s.max_revisits
    kept = without if len(without) <= keep else without[: keep - 1] + without[-1:]
    p.revisit_count = count
    first_end = _visit_end(mem, views, p.found.key(0), s, asof, views[:16])
    p.later_visit = first_end is not None and last[0] >= first_end
    return kept


def read_revisits(places: list[Place], kept: list[list[int]], q: np.ndarray) -> None:
    """Each place's revisits kept (`revisits`), as hits scored from their vectors: read in one
    store call with the records every answer shows (each place's first, last and best
    sighting)."""
    got = read_rows([(p, [0, len(p.found) - 1, p.best_row]) for p in places], [i for k in kept for i in k])
    for p, ids in zip(places, kept, strict=True):
        p.revisits = [_revisit(got[i], q) for i in ids if i in got]


def _revisit(r: MemoryRecord, q: np.ndarray) -> Hit:
    """A revisit as a hit: the record (its embedding dropped) and its score."""
    assert r.embedding is not None
    return Hit(memory=replace(r, embedding=None), score=float(np.dot(r.embedding, q)))


def _visit_end(
    mem: Core, views: np.ndarray, start: tuple[float, int], s: ChangeConfig, asof: Filter, near: np.ndarray
) -> float | None:
    """When the robot first looked away from the place after `start` ((time, id) of one of its
    sightings): the time of the first later memory that overlaps none of the place's sightings
    (`views`, as `_poses` gives them; None if it never did). `near`: a few of them, those
    taken about when `start` was: a memory that overlaps one of those is not away, and only
    the others are tested against every sighting, first ones first."""
    cursor, read, size = start, 0, 16  # mostly the robot looks away at once
    while read < s.max_walk:
        page = cameras(mem, cursor[0], size, asof)
        fresh = page.take(_after(page, cursor))
        away = _first_away(fresh.poses, views, near, s)
        if away is not None:
            return float(fresh.t[away])
        read += len(fresh)
        if len(page) < size or (not len(fresh) and size >= _PAGE):
            return None
        if len(fresh):
            cursor = (float(fresh.t[-1]), int(fresh.ids[-1]))
        size = min(_PAGE, 4 * size)
    return None


def _first_away(cams: np.ndarray, views: np.ndarray, near: np.ndarray, s: ChangeConfig) -> int | None:
    """The first row of `cams` that overlaps none of `views` (`near`: some of them)."""
    maybe = np.flatnonzero(~overlapping_poses(cams, near, s))
    for chunk in (maybe[:2], maybe[2:8], maybe[8:]):  # mostly the first one is away
        if len(chunk):
            away = chunk[~overlapping_poses(cams[chunk], views, s)]
            if len(away):
                return int(away[0])
    return None


def merge(places: list[Place]) -> list[Place]:
    """Places that grew into each other (a later sighting of one is a sighting of another)
    become one; returns the places that took others in (their revisits must be redone)."""
    grown: list[Place] = []
    seen: list[Place] = []  # the places before this one (those still in `places` share no id)
    for p in list(places):
        for other in [o for o in seen if o in places and among(p.found.ids, o.found.ids).any()]:
            p.found = p.found.union(other.found)
            places.remove(other)
            grown = [g for g in grown if g is not other]
            if p not in grown:
                grown.append(p)
        seen.append(p)
    return grown
