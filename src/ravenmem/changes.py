"""Where is it now? Sightings, revisits and verdicts for a world that changes.

A memory is a log of views, not a map of things: when a mug moves, the old views of it stay
and still match "a mug" as well as ever. To answer from the latest evidence, this module asks,
for every place where the thing was seen, whether the robot looked at that place again later:

1. **Sightings.** Memories that show the thing: cosine to the query at least `threshold`,
   halfway (by default) between a typical memory's score (the median of a sample spread over
   the memory) and the best match. The newest sightings are searched for explicitly (time
   windows walking back from the end), so a thing seen ten thousand times in January and once
   in May is found in May.
2. **Places.** Sightings are grouped into places: a sighting joins the best earlier one whose
   view it overlaps (cameras within `view_radius` metres, orientations within
   `view_angle_deg`: the full 3-D rotation when both poses carry a quaternion, else the yaw),
   and sightings that follow each other in time with no memory in between are one place (the
   robot kept the thing in view while it moved).
3. **Revisits.** A later memory whose view overlaps one of the place's sightings looks at the
   same scene. If it scores at least the threshold it is one more sighting (the place's last
   sighting moves on); if not, it is a view of the place without the thing. Only views after
   the robot looked away *and* a pass later (`episode_gap_s`, by default 30 times the
   memory's mean time between keyframes while recording) count: frames of the same pass that lose the thing
   at the edge of the picture are not evidence that it left.
4. **Verdicts**, per place, from its last sighting at T1:
   - `still there`: no later visit without it, and it was seen there on more than one visit;
   - `not revisited`: seen on one visit only, and nothing has looked at the place since;
   - `moved`: a later visit (first at T2) looked at the place without it, and it was seen
     elsewhere since: on a later pass than T1, or after T2;
   - `gone`: a later visit looked at the place without it, and it was not seen elsewhere since
     (views of it from elsewhere on the same pass as T1 do not count: the same spot, another
     angle).
5. **The thing's status** (`Whereabouts.status`): the verdict of its newest place, except
   that it is `gone` when a place where it was seen on that same last pass was looked at
   again, after the newest sighting, without it (one object seen from several viewpoints is
   several places here; this is how their evidence is joined).

Places come newest first (by last sighting): unless the status is gone, the first one is where
the thing is now (`Whereabouts.now`). `before` sets the "as of" time: only memories up to it
count, so "where was it at noon?" is the same question asked of the past.

Limits (see docs/memory.md, "A world that changes"): views are compared, things are not
located, so a place seen again only from a new viewpoint counts as not revisited; a thing
moved within the same picture still shows in it; two instances of a thing look alike.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from .errors import InputError
from .timeparse import fmt_time
from .types import Filter, Hit, MemoryRecord, Region

if TYPE_CHECKING:
    from .memory import Memory, Near, TimeLike

Verdict = Literal["still there", "moved", "gone", "not revisited"]
VERDICTS: tuple[Verdict, ...] = ("still there", "moved", "gone", "not revisited")
_MAX_K = 1000  # the stores' page limit (ravenmem.tools.MAX_K)
_PAGE = 256  # memories read per step of a walk forward in time


@dataclass(frozen=True)
class ChangeSettings:
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
        if not 1 <= self.pool <= _MAX_K or not 0.0 < self.match_ratio < 1.0:
            raise InputError(f"changes: pool must be 1..{_MAX_K} and 0 < match_ratio < 1: {self}")
        if self.view_radius <= 0 or not 0 < self.view_angle_deg <= 180 or self.max_revisits < 1:
            raise InputError(
                f"changes: view_radius > 0, 0 < view_angle_deg <= 180, max_revisits >= 1: {self}"
            )
        if self.episode_gap_s is not None and not self.episode_gap_s > 0:
            raise InputError(f"changes: episode_gap_s must be > 0 (or None), got {self.episode_gap_s}")


@dataclass(eq=False)
class Place:
    """One place where the thing was seen, and what later visits say about it. `sightings` and
    `revisits` (views of the place without the thing, after the robot looked away; at most
    `max_revisits` kept: the first ones and the latest) are chronological."""

    index: int
    sightings: list[Hit]
    revisits: list[Hit] = field(default_factory=list)
    revisit_count: int = 0
    later_visit: bool = False
    verdict: Verdict = "not revisited"
    moved_to: int | None = None  # moved: the place of its newest sighting since
    seen_since: Hit | None = None  # moved: the first sighting elsewhere since
    newest_since: Hit | None = None  # moved: the newest sighting elsewhere since

    @property
    def first(self) -> MemoryRecord:
        return self.sightings[0].memory

    @property
    def last(self) -> MemoryRecord:
        return self.sightings[-1].memory

    @property
    def seen(self) -> int:
        """How many memories showed it here: a consolidated sighting counts what it stands for."""
        return sum(h.count for h in self.sightings)

    @property
    def first_t(self) -> float:
        """When it was first seen here (a consolidated sighting's span starts earlier than its t)."""
        return min(h.span[0] if h.span else h.memory.t for h in self.sightings)

    @property
    def last_t(self) -> float:
        """When it was last seen here (a consolidated sighting's span ends later than its t)."""
        return max(h.span[1] if h.span else h.memory.t for h in self.sightings)

    @property
    def best(self) -> Hit:
        return max(self.sightings, key=lambda h: h.score or 0.0)

    @property
    def revisited(self) -> float | None:
        """When the robot first looked at the place again without seeing the thing."""
        return self.revisits[0].memory.t if self.revisits else None

    def revisit_ids(self) -> str:
        ids = ", ".join(f"m{h.memory.id}" for h in self.revisits)
        more = self.revisit_count - len(self.revisits)
        return ids + (f" and {more} more" if more > 0 else "")

    def sentence(self) -> str:
        """The place and its verdict in one line, with the times and memory ids it rests on."""
        p, n = self.last.pose, self.seen
        seen = (
            f"seen {n} times from {fmt_time(self.first_t)} to {fmt_time(self.last_t)}"
            if n > 1
            else f"seen once at {fmt_time(self.last_t)}"
        )
        head = f"place {self.index} (camera at x={p.x:.2f} y={p.y:.2f}): {seen} (last m{self.last.id})"
        if self.verdict in ("moved", "gone"):
            assert self.revisited is not None
            back = f"looked at again at {fmt_time(self.revisited)} ({self.revisit_ids()}) without it"
            if self.verdict == "moved" and self.seen_since is not None and self.newest_since is not None:
                first, newest = self.seen_since.memory, self.newest_since.memory
                where = f"at place {self.moved_to} (m{newest.id} at {fmt_time(newest.t)})"
                if first.id == newest.id:
                    return f"{head}; {back}: moved, seen since {where}"
                since = f"seen elsewhere from {fmt_time(first.t)} (m{first.id}), latest {where}"
                return f"{head}; {back}: moved, {since}"
            return f"{head}; {back}, and not seen anywhere since: gone"
        if self.verdict == "still there":
            return f"{head}; seen there again on a later visit, nothing since without it: still there"
        return f"{head}; nothing has looked at that place since: not revisited"

    def as_dict(self) -> dict[str, Any]:
        """Plain data (the `change` of a hit in `--json`, HTTP and MCP; the agent's answer)."""
        p = self.last.pose
        since = self.seen_since.memory if self.seen_since is not None else None
        return {
            "place": self.index,
            "verdict": self.verdict,
            "x": p.x,
            "y": p.y,
            "z": p.z,
            "sightings": self.seen,
            "first_seen": self.first_t,
            "last_seen": self.last_t,
            "last_seen_time": fmt_time(self.last_t),
            "last_seen_id": self.last.id,
            "later_visit": self.later_visit,
            "revisited": self.revisited,
            "revisited_time": fmt_time(self.revisited) if self.revisited is not None else None,
            "revisit_ids": [h.memory.id for h in self.revisits],
            "revisit_count": self.revisit_count,
            "moved_to": self.moved_to,
            "seen_since": since.t if since is not None else None,
            "seen_since_id": since.id if since is not None else None,
            "newest_since_id": self.newest_since.memory.id if self.newest_since is not None else None,
            "text": self.sentence(),
        }


@dataclass
class ChangeHit(Hit):
    """A hit of the latest mode: a place's last sighting (`role="sighting"`) or a later view of
    it without the thing (`role="revisit"`); `change` is the place's `as_dict()` plus the role
    and the thing's overall `status`."""

    change: dict[str, Any] = field(default_factory=dict)


@dataclass
class Whereabouts:
    """Every place the thing was seen, newest last sighting first, with their verdicts, and the
    verdict on the thing itself (`status`): its newest place's, except that a thing whose
    newest place was not looked at again is `gone` when a place where it was seen on that same
    pass was looked at again, after its last sighting, without it (`status_note` says which)."""

    query: str
    places: list[Place]
    threshold: float
    floor: float
    best: float
    status: Verdict | None = None
    status_note: str = ""

    @property
    def now(self) -> Place | None:
        """Where the thing is now: its newest place, unless the thing is gone (None then, and
        when it was not seen at all)."""
        return self.places[0] if self.places and self.status != "gone" else None

    @property
    def latest(self) -> Place | None:
        """The place of the newest sighting, whatever the verdict."""
        return self.places[0] if self.places else None

    @property
    def moved_from(self) -> list[Place]:
        """Older places it was seen at and is known to have left."""
        return [p for p in self.places if p.verdict == "moved"]

    def summary(self) -> str:
        """The thing's status, then every place with its verdict: what the agent reads."""
        if not self.places:
            return f"{self.query}: not seen (no memory stands out; best score {self.best:.3f})"
        head = f"{self.query}: {self.status}" + (f" ({self.status_note})" if self.status_note else "")
        return head + ". " + "; ".join(p.sentence() for p in self.places)

    def hits(self, k: int, revisits: int = 2) -> list[ChangeHit]:
        """The tool's results: per place (newest first, up to `k` places) its last sighting,
        then, for places moved or gone, the first and the latest view without the thing."""
        out: list[ChangeHit] = []
        thing = {"status": self.status, "status_note": self.status_note}
        for p in self.places[:k]:
            info = {**p.as_dict(), **thing}
            last = p.sightings[-1]
            out.append(
                ChangeHit(
                    memory=last.memory,
                    score=last.score,
                    count=last.count,
                    span=last.span,
                    change={**info, "role": "sighting"},
                )
            )
            if p.verdict in ("moved", "gone"):
                shown = p.revisits[:1] + (p.revisits[-1:] if len(p.revisits) > 1 else [])
                for h in shown[:revisits]:
                    out.append(
                        ChangeHit(
                            memory=h.memory,
                            score=h.score,
                            count=h.count,
                            span=h.span,
                            change={**info, "role": "revisit"},
                        )
                    )
        return out


def last_seen(
    mem: Memory,
    query: str | None = None,
    *,
    image: np.ndarray | None = None,
    memory_id: int | None = None,
    vector: np.ndarray | None = None,
    after: TimeLike = None,
    before: TimeLike = None,
    near: Near | None = None,
    min_score: float | None = None,
    settings: ChangeSettings | None = None,
) -> Whereabouts:
    """Where the thing described by `query` (or `image`, a stored memory's picture `memory_id`,
    or a query `vector`) was seen, place by place, and whether it is still there.

    `after`/`near` restrict the sightings, `before` is the "as of" time for everything.
    `min_score`: a floor under the threshold (the offline reasoner passes its calibrated one).
    """
    s = settings or ChangeSettings()
    mem.time_span()  # an empty memory is an error (EmptyMemoryError), as for every search
    q, label = _query_vector(mem, query, image, memory_id, vector)
    filt = mem.make_filter(after, before, near)
    asof = Filter(before=filt.before)
    pool = _search(mem, q, min(s.pool, mem.count()), filt)
    if not pool:
        return Whereabouts(label, [], math.inf, 0.0, 0.0)
    best = max(sc for _, sc in pool.values())
    floor = _floor(mem, q, s.floor_sample)
    thr = floor + s.match_ratio * (best - floor) if best > floor + 1e-6 else math.inf
    if min_score is not None:
        thr = max(thr, float(min_score))
    pool.update(_recent(mem, q, filt, thr, s))
    seen = {i: Hit(memory=r, score=sc) for i, (r, sc) in pool.items() if sc >= thr}
    if not seen:
        return Whereabouts(label, [], thr, floor, best)
    places = [Place(0, g) for g in _group(mem, sorted(seen.values(), key=_chrono), s)]
    gap = s.episode_gap_s if s.episode_gap_s is not None else 30.0 * _spacing(mem)
    for p in places:
        _follow(mem, p, q, thr, s, asof, gap)
    for p in _merge(places):
        _follow(mem, p, q, thr, s, asof, gap)
    places.sort(key=lambda p: _chrono(p.sightings[-1]), reverse=True)
    for i, p in enumerate(places, 1):
        p.index = i
    # consolidated memories stand for several: counts and spans (ravenmem.lifelong) on the evidence
    mem._grouped([h for p in places for h in (*p.sightings, *p.revisits)])
    out = Whereabouts(label, places, thr, floor, best)
    _judge(out, _episodes(places, gap))
    return out


# ---------------------------------------------------------------------------- the query
def _query_vector(
    mem: Memory, query: str | None, image: np.ndarray | None, memory_id: int | None, vector: np.ndarray | None
) -> tuple[np.ndarray, str]:
    given = [v is not None for v in (query, image, memory_id, vector)]
    if sum(given) != 1:
        raise InputError("last_seen needs exactly one of: a text query, an image, a memory_id or a vector")
    if query is not None:
        if not isinstance(query, str) or not query.strip():
            raise InputError("last_seen: empty text query")
        return np.asarray(mem.embedder.embed_texts([query])[0], np.float32), query
    if image is not None:
        return np.asarray(mem.embedder.embed_images([image])[0], np.float32), "the image"
    if memory_id is not None:
        try:
            (rec,) = mem.store.get([int(memory_id)], with_embeddings=True)
        except KeyError:
            raise InputError(f"memory_id {memory_id}: no such memory") from None
        assert rec.embedding is not None
        return np.asarray(rec.embedding, np.float32), f"memory m{rec.id}"
    v = np.asarray(vector, np.float32).reshape(-1)
    if v.shape != (mem.dim,) or not np.all(np.isfinite(v)):
        raise InputError(f"last_seen: the vector must be {mem.dim} finite numbers, got shape {v.shape}")
    return v, "the vector"


def _chrono(h: Hit) -> tuple[float, int]:
    return (h.memory.t, h.memory.id)


def _search(mem: Memory, q: np.ndarray, k: int, filt: Filter) -> dict[int, tuple[MemoryRecord, float]]:
    scored = mem.store.search_vector(q, max(1, min(k, _MAX_K)), filt)
    recs = {r.id: r for r in _sample(mem, [i for i, _ in scored])}
    return {i: (recs[i], float(sc)) for i, sc in scored if i in recs}


def _scores(mem: Memory, q: np.ndarray, ids: Sequence[int]) -> list[tuple[MemoryRecord, float]]:
    recs = _sample(mem, ids, embeddings=True)
    out = []
    for r in recs:
        assert r.embedding is not None
        out.append((r, float(np.dot(r.embedding, q))))
        r.embedding = None
    return out


def _sample(mem: Memory, ids: Sequence[int], embeddings: bool = False) -> list[MemoryRecord]:
    """The records of `ids` that exist (ids a forget removed are skipped)."""
    return mem.stored(ids, with_embeddings=embeddings)


def _spread(mem: Memory, n: int) -> list[int]:
    """About n ids spread evenly over the memory: ids grow with insertion, so between the ids
    of the oldest and the newest memory (a few may be missing: `_sample` skips them). The
    stored times, not `mem.time_span()`: a consolidated memory's span reaches past its newest
    representative's own time, where no memory starts."""
    st = mem.store.stats()
    t0, t1 = float(st["t_min"]), float(st["t_max"])  # type: ignore[arg-type]
    ends = [r.id for t in (t0, t1) for r in mem.store.by_time(t, 1)]
    lo, hi = min(ends), max(ends)
    return sorted({int(i) for i in np.linspace(lo, hi, max(1, min(n, hi - lo + 1)))})


def _floor(mem: Memory, q: np.ndarray, n: int) -> float:
    """A typical memory's score: the median over memories spread evenly over the memory."""
    recs = _sample(mem, _spread(mem, n), embeddings=True)
    scores = [float(np.dot(r.embedding, q)) for r in recs if r.embedding is not None]
    return float(np.median(scores)) if scores else 0.0


def _recent(
    mem: Memory, q: np.ndarray, filt: Filter, thr: float, s: ChangeSettings
) -> dict[int, tuple[MemoryRecord, float]]:
    """The newest sightings: the best `pool` memories in time windows that grow backwards from
    the end (a 64th of the span, then 4 times wider) until one holds a sighting."""
    t0, t1 = mem.time_span()
    lo = max(t0, filt.after) if filt.after is not None else t0
    hi = min(t1, filt.before) if filt.before is not None else t1
    width = max((hi - lo) / 64.0, 1e-3)
    for _ in range(s.recency_windows):
        start = max(lo, hi - width)
        found = _search(mem, q, s.pool, Filter(after=start, before=hi, region=filt.region))
        if any(sc >= thr for _, sc in found.values()) or start <= lo:
            return found
        width *= 4.0
    return {}


# ---------------------------------------------------------------------------- views and places
def _angle(a: MemoryRecord, b: MemoryRecord) -> float:
    """Degrees between two camera orientations: the full rotation when both have a quaternion."""
    qa, qb = a.pose.quat, b.pose.quat
    if qa is not None and qb is not None:
        dot = abs(sum(x * y for x, y in zip(qa, qb)))
        return math.degrees(2.0 * math.acos(min(1.0, dot)))
    d = (b.pose.yaw - a.pose.yaw + math.pi) % (2.0 * math.pi) - math.pi
    return abs(math.degrees(d))


def overlaps(a: MemoryRecord, b: MemoryRecord, s: ChangeSettings | None = None) -> bool:
    """Whether two memories look at the same scene: cameras within `view_radius` (in the plane)
    and turned at most `view_angle_deg` from each other."""
    s = s or ChangeSettings()
    close = math.hypot(a.pose.x - b.pose.x, a.pose.y - b.pose.y) <= s.view_radius
    return close and _angle(a, b) <= s.view_angle_deg


def _group(mem: Memory, hits: list[Hit], s: ChangeSettings) -> list[list[Hit]]:
    """Places: each sighting joins the best-scored earlier seed whose view it overlaps (no
    chains: a robot turning on the spot does not make one place of every direction), and
    sightings that follow each other in time with no memory in between are one place (the
    robot kept the thing in view while it moved)."""
    n = len(hits)
    parent = list(range(n))

    def root(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    seeds: list[int] = []
    for i in sorted(range(n), key=lambda i: -(hits[i].score or 0.0)):
        home = next((j for j in seeds if overlaps(hits[i].memory, hits[j].memory, s)), None)
        if home is None:
            seeds.append(i)
        else:
            parent[root(i)] = root(home)
    for i in range(n - 1):
        a, b = hits[i].memory, hits[i + 1].memory
        if root(i) == root(i + 1):
            continue
        step = mem.store.by_time(a.t, 2, Filter(before=b.t))
        if len(step) == 2 and step[0].id == a.id and step[1].id == b.id:
            parent[root(i)] = root(i + 1)
    groups: dict[int, list[Hit]] = {}
    for i, h in enumerate(hits):
        groups.setdefault(root(i), []).append(h)
    return [sorted(g, key=_chrono) for g in groups.values()]


def _disc(p: Place, s: ChangeSettings) -> tuple[Region, list[MemoryRecord]]:
    """The cameras a later view is compared with (the last 16 sightings and the best one), and
    a disc around them that holds every camera overlapping one of them."""
    cams = [h.memory for h in p.sightings[-16:]]
    best = p.best.memory
    if all(r.id != best.id for r in cams):
        cams.append(best)
    cx = float(np.mean([r.pose.x for r in cams]))
    cy = float(np.mean([r.pose.y for r in cams]))
    reach = max(math.hypot(r.pose.x - cx, r.pose.y - cy) for r in cams)
    return Region(cx, cy, reach + s.view_radius), cams


def _views(
    mem: Memory, q: np.ndarray, recs: Sequence[MemoryRecord], cams: list[MemoryRecord], s: ChangeSettings
) -> list[Hit]:
    """The records whose view overlaps one of `cams`, scored against the query, chronological."""
    near = [r for r in recs if any(overlaps(r, c, s) for c in cams)]
    scored = _scores(mem, q, [r.id for r in near]) if near else []
    return sorted((Hit(memory=r, score=sc) for r, sc in scored), key=_chrono)


def _newest_views(
    mem: Memory, q: np.ndarray, p: Place, s: ChangeSettings, asof: Filter, thr: float | None
) -> list[Hit]:
    """The newest views of the place after its last sighting (with `thr`: the newest that show
    the thing): time windows growing backwards from the end, inside the place's disc."""
    disc, cams = _disc(p, s)
    lo = p.last.t
    hi = asof.before if asof.before is not None else mem.time_span()[1]
    if thr is not None:  # one search over the whole time first: mostly there is no later sighting
        found = mem.store.search_vector(q, s.pool, Filter(after=lo, before=hi, region=disc))
        recs = _sample(mem, [i for i, sc in found if sc >= thr])
        if not any(_chrono(h) > _chrono(p.sightings[-1]) for h in _views(mem, q, recs, cams, s)):
            return []
    width = max((hi - lo) / 64.0, 1e-3)
    for _ in range(s.recency_windows + 4):
        start = max(lo, hi - width)
        filt = Filter(after=start, before=hi, region=disc)
        if thr is None:
            recs = mem.store.by_time(start, s.pool, filt)
        else:
            found = mem.store.search_vector(q, s.pool, filt)
            recs = _sample(mem, [i for i, sc in found if sc >= thr])
        got = [h for h in _views(mem, q, recs, cams, s) if _chrono(h) > _chrono(p.sightings[-1])]
        if thr is not None:
            got = [h for h in got if (h.score or 0.0) >= thr]
        if got or start <= lo:
            return got
        width *= 4.0
    return []


def _follow(
    mem: Memory, p: Place, q: np.ndarray, thr: float, s: ChangeSettings, asof: Filter, gap: float
) -> None:
    """Grow the place with its newest later sightings, then collect the later views without the
    thing: after the robot looked away, and at least a pass (`gap` s) after the last sighting."""
    for _ in range(s.max_rounds):
        more = _newest_views(mem, q, p, s, asof, thr)
        if not more:
            break
        known = {h.memory.id for h in p.sightings}
        p.sightings = sorted(p.sightings + [h for h in more if h.memory.id not in known], key=_chrono)
    end = _visit_end(mem, p, p.last, s, asof)
    start = p.last.t + gap if end is None else max(end, p.last.t + gap)
    disc, cams = _disc(p, s)
    first = mem.store.by_time(start, s.pool, Filter(before=asof.before, region=disc))
    without = [h for h in _views(mem, q, first, cams, s) if (h.score or 0.0) < thr]
    p.revisit_count = len(without)
    if without:
        newest = [h for h in _newest_views(mem, q, p, s, asof, None) if (h.score or 0.0) < thr]
        if newest and newest[-1].memory.id not in {h.memory.id for h in without}:
            without.append(newest[-1])
            p.revisit_count = max(p.revisit_count + 1, len(without))
    keep = s.max_revisits
    p.revisits = without if len(without) <= keep else without[: keep - 1] + without[-1:]
    first_end = _visit_end(mem, p, p.first, s, asof)
    p.later_visit = first_end is not None and p.last.t >= first_end


def _visit_end(mem: Memory, p: Place, start: MemoryRecord, s: ChangeSettings, asof: Filter) -> float | None:
    """When the robot first looked away from the place after `start`: the time of the first
    later memory that overlaps none of the place's sightings (None if it never did)."""
    views = [h.memory for h in p.sightings]
    cursor, read = (start.t, start.id), 0
    while read < s.max_walk:
        page = mem.store.by_time(cursor[0], _PAGE, asof)
        fresh = [r for r in page if (r.t, r.id) > cursor]
        for r in fresh:
            if not any(overlaps(r, v, s) for v in views):
                return r.t
        read += len(fresh)
        if len(page) < _PAGE or not fresh:
            return None
        cursor = (fresh[-1].t, fresh[-1].id)
    return None


def _merge(places: list[Place]) -> list[Place]:
    """Places that grew into each other (a later sighting of one is a sighting of another)
    become one; returns the places that took others in (their revisits must be redone)."""
    owner: dict[int, Place] = {}
    grown: list[Place] = []
    for p in list(places):
        for other in {owner[h.memory.id] for h in p.sightings if h.memory.id in owner}:
            if other not in places:
                continue
            ids = {h.memory.id for h in p.sightings}
            p.sightings = sorted(
                p.sightings + [h for h in other.sightings if h.memory.id not in ids], key=_chrono
            )
            places.remove(other)
            grown = [g for g in grown if g is not other]
            if p not in grown:
                grown.append(p)
        for h in p.sightings:
            owner[h.memory.id] = p
    return grown


def _spacing(mem: Memory, n: int = 64) -> float:
    """The robot's usual time between keyframes while recording: the mean time between a memory
    and the next one stored (ids grow with insertion), over pairs spread over the memory, not
    counting breaks (gaps over 10 times the median: the robot was off or elsewhere). The mean,
    not the median: keyframes come fast while turning and slowly while driving."""
    ids = _spread(mem, n)
    first = ids[:-1] if len(ids) > 1 else ids
    recs = {r.id: r.t for r in _sample(mem, sorted(set(first) | {i + 1 for i in first}))}
    diffs = np.array(
        [recs[i + 1] - recs[i] for i in first if i in recs and i + 1 in recs and recs[i + 1] > recs[i]]
    )
    if diffs.size == 0:
        return 1.0
    return float(diffs[diffs <= 10.0 * np.median(diffs)].mean())


def _episodes(places: list[Place], gap: float) -> dict[int, int]:
    """Memory id -> pass: sightings of the thing (any place) in a row with no gap over `gap` s."""
    hits = sorted((h for p in places for h in p.sightings), key=_chrono)
    out, ep, prev = {}, 0, None
    for h in hits:
        if prev is not None and h.memory.t - prev > gap:
            ep += 1
        out[h.memory.id] = ep
        prev = h.memory.t
    return out


def _judge(w: Whereabouts, episode: dict[int, int]) -> None:
    """Place verdicts (moved / gone when a later visit looked without seeing it, else still
    there / not revisited), then the thing's status. `w.places` is newest first."""
    for p in w.places:
        if not p.revisits:
            p.verdict = "still there" if p.later_visit else "not revisited"
            continue
        t1, t2, ep = p.last.t, p.revisits[0].memory.t, episode[p.last.id]
        since = [
            (h, q)
            for q in w.places
            if q is not p
            for h in q.sightings
            if h.memory.t > t2 or (h.memory.t > t1 and episode[h.memory.id] != ep)
        ]
        if since:  # seen elsewhere on a later pass, or after it was found missing here: moved
            newest, where = max(since, key=lambda hq: _chrono(hq[0]))
            p.verdict, p.moved_to, p.newest_since = "moved", where.index, newest
            p.seen_since = min((h for h, _ in since), key=_chrono)
        else:  # seen elsewhere only on the pass it was last seen here (another view of it): gone
            p.verdict = "gone"
    top = w.places[0]
    w.status = top.verdict
    if top.verdict != "gone":
        ep, t_last = episode[top.last.id], top.last.t
        for q in w.places[1:]:
            later = [h for h in q.revisits if h.memory.t > t_last]
            if later and episode[q.last.id] == ep:
                w.status = "gone"
                w.status_note = (
                    f"last seen at {fmt_time(t_last)} from place {top.index} (m{top.last.id}); on that "
                    f"pass it was also seen from place {q.index} (last m{q.last.id}), which was looked "
                    f"at again at {fmt_time(later[0].memory.t)} (m{later[0].memory.id}) without it"
                )
                break
