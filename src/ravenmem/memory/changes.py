"""Where is it now? Sightings, revisits and verdicts for a world that changes.

A memory is a log of views, not a map of things: when a mug moves, the old views of it stay
and still match "a mug" as well as ever. To answer from the latest evidence, this module asks,
for every place where the thing was seen, whether the robot looked at that place again later:

1. **Sightings.** Memories that show the thing: cosine to the query at least `threshold`,
   halfway (by default) between a typical memory's score (the median of a sample spread over
   the memory) and the best match. The newest sightings are searched for explicitly (from the
   newest sighting among the best matches, searching only what came after it: see
   `ravenmem.memory.newest`), so a thing seen ten thousand times in January and once in May is
   found in May.
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
import os
from pathlib import Path

import numpy as np

from ..errors import InputError
from ..imageio import read_image
from ..timeparse import fmt_time
from ..types import Filter, check_picture
from .core import Core, check_text
from .newest import Later, cameras_of, newest_sightings
from .places import Place, Sightings, Verdict, Whereabouts, among, read_rows
from .protocol import MAX_K, Near, TimeLike
from .seen_index import seen_index
from .views import ChangeConfig, group_sightings, grow, merge, read_revisits, revisits

__all__ = ["ChangeConfig", "Changes", "Place", "Verdict", "Whereabouts"]


class Changes(Core):
    """`Memory.last_seen`."""

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
        config: ChangeConfig | None = None,
    ) -> Whereabouts:
        """Where a thing was seen, place by place (newest first), and whether each place still
        shows it: `still there`, `not revisited`, `moved` or `gone` (see the module docstring).
        The thing is a `query` text, an `image` (an array or an image file), a stored memory's
        picture (`memory_id`) or a query `vector`. `after`/`near` restrict the sightings,
        `before` is the "as of" time for everything; `.now` is the place it is at now, if any.
        `min_score` puts a floor under the match threshold (the offline reasoner passes its
        calibrated one); `config` sets the rules' numbers.
        """
        if query is not None:
            check_text(query)
        img = read_image(Path(image)) if isinstance(image, (str, os.PathLike)) else image
        s = config or ChangeConfig()
        self.time_span()  # an empty memory is an error (EmptyMemoryError), as for every search
        q, label = _query_vector(self, query, img, memory_id, vector)
        filt = self.make_filter(after, before, near)
        asof = Filter(before=filt.before)
        k = max(1, min(s.pool, self.count(), MAX_K))  # good matches, not the exact best k:
        scored = self.store.search_vector(q, k, filt, candidates=k)  # re-ranks k, not 4 k
        if not scored:
            return Whereabouts(label, [], math.inf, 0.0, 0.0)
        index = seen_index(self, s.floor_sample)  # whole-memory facts, read once per state
        floor = index.floor(q)
        pool, thr, best = _pool(self, scored, floor, s.match_ratio, min_score)
        recent, complete = _recent(self, q, pool, filt, thr, s)
        seen = pool.union(recent)
        if not len(seen):
            return Whereabouts(label, [], thr, floor, best)
        places = [Place(0, seen.take(g), load=self.stored) for g in group_sightings(self, seen, s)]
        gap = s.episode_gap_s if s.episode_gap_s is not None else 30.0 * index.spacing
        later = Later(self, q, thr, asof.before, s.pool, s.max_rounds, 2.0 * s.view_radius)
        if complete is not None:  # the newest window answers for places seen only in it
            later.knows(complete, filt.region, recent)
        known = {
            id(p): grow(p, s, later) for p in sorted(places, key=lambda p: p.found.key(-1))
        }  # earliest first (see Later)
        for p in merge(places):  # a place that took others in grows again from its new last
            known[id(p)] = grow(p, s, later)
        kept = [revisits(self, p, q, thr, s, asof, gap, known[id(p)]) for p in places]  # once, of those left
        read_revisits(places, kept, q)
        places.sort(key=lambda p: p.found.key(-1), reverse=True)
        for i, p in enumerate(places, 1):
            p.index = i
        groups = self.groups()  # consolidated memories stand for several: counts and spans
        if groups:
            for p in places:
                p.found = p.found.grouped(groups)
            self.grouped([h for p in places for h in p.revisits])
        out = Whereabouts(label, places, thr, floor, best)
        since = _judge(out, _episodes(places, gap))
        shown = [(p, [0, len(p.found) - 1, p.best_row]) for p in places]
        read_rows(shown + [(other, [row]) for _, _, other, row in since])  # the records an answer shows
        for p, name, other, row in since:
            setattr(p, name, other.hit(row))
        return out


def _query_vector(
    mem: Core, query: str | None, image: np.ndarray | None, memory_id: int | None, vector: np.ndarray | None
) -> tuple[np.ndarray, str]:
    given = [v is not None for v in (query, image, memory_id, vector)]
    if sum(given) != 1:
        raise InputError("last_seen needs exactly one of: a text query, an image, a memory_id or a vector")
    if query is not None:
        if not isinstance(query, str) or not query.strip():
            raise InputError("last_seen: empty text query")
        return np.asarray(mem.embedder.embed_texts([query])[0], np.float32), query
    if image is not None:
        check_picture(image, "query image")
        return np.asarray(mem.embedder.embed_images([image])[0], np.float32), "the image"
    if memory_id is not None:
        rec = mem.embedded(memory_id)
        return np.asarray(rec.embedding, np.float32), f"memory m{rec.id}"
    v = np.asarray(vector, np.float32).reshape(-1)
    if v.shape != (mem.dim,) or not np.all(np.isfinite(v)):
        raise InputError(f"last_seen: the vector must be {mem.dim} finite numbers, got shape {v.shape}")
    return v, "the vector"


def _pool(
    mem: Core, scored: list[tuple[int, float]], floor: float, ratio: float, min_score: float | None
) -> tuple[Sightings, float, float]:
    """The pool's sightings (the rest of the pool is below the threshold and never shown), the
    threshold and the best score they set. A memory no longer stored is left out, and the
    threshold is set again without it when it was the best."""
    ids = np.array([i for i, _ in scored], np.int64)
    scores = np.array([sc for _, sc in scored], np.float64)
    while len(ids):
        best = float(scores.max())
        thr = floor + ratio * (best - floor) if best > floor + 1e-6 else math.inf
        if min_score is not None:
            thr = max(thr, float(min_score))
        want = scores >= thr
        if not want.any():
            return Sightings.none(), thr, best
        cams = cameras_of(mem, ids[want].tolist())  # the stored ones, in the order given
        if len(cams) == int(want.sum()):
            return Sightings.of(cams, scores[want]), thr, best
        keep = ~want | among(ids, cams.ids)
        ids, scores = ids[keep], scores[keep]
    return Sightings.none(), math.inf, 0.0


def _recent(
    mem: Core,
    q: np.ndarray,
    pool: Sightings,
    filt: Filter,
    thr: float,
    s: ChangeConfig,
) -> tuple[Sightings, float | None]:
    """The newest sightings: only memories after the newest sighting in the pool can be newer,
    so the search goes on from there (`newest_sightings`: a few searches, each later); and
    from when on they are all there."""
    start = float(pool.t.max()) if len(pool) else filt.after
    return newest_sightings(
        mem, q, start, filt.before, thr, region=filt.region, pool=s.pool, steps=s.max_rounds
    )


def _episodes(places: list[Place], gap: float) -> list[np.ndarray]:
    """Per place, the pass of each sighting: sightings of the thing (any place) in a row with
    no gap over `gap` s are one pass."""
    ids = np.concatenate([p.found.ids for p in places])
    t = np.concatenate([p.found.t for p in places])
    order = np.lexsort((ids, t))
    ep = np.empty(len(ids), np.int64)
    ep[order] = np.concatenate([[0], np.cumsum(np.diff(t[order]) > gap)])
    return np.split(ep, np.cumsum([len(p.found) for p in places])[:-1])


def _judge(w: Whereabouts, passes: list[np.ndarray]) -> list[tuple[Place, str, Place, int]]:
    """Place verdicts (moved / gone when a later visit looked without seeing it, else still
    there / not revisited), then the thing's status. `w.places` is newest first; `passes`
    are their sightings' passes (`_episodes`). Returns where a moved place's thing was seen
    since, as (place, `seen_since` or `newest_since`, the other place, its row): hits made
    once the answer's records are read together."""
    since: list[tuple[Place, str, Place, int]] = []
    for p, p_pass in zip(w.places, passes, strict=True):
        if not p.revisits:
            p.verdict = "still there" if p.later_visit else "not revisited"
            continue
        t1, t2, ep = float(p.found.t[-1]), p.revisits[0].memory.t, int(p_pass[-1])
        newest: tuple[tuple[float, int], Place, int] | None = None
        first: tuple[tuple[float, int], Place, int] | None = None
        for q, q_pass in zip(w.places, passes, strict=True):
            if q is p:
                continue
            rows = np.flatnonzero((q.found.t > t2) | ((q.found.t > t1) & (q_pass != ep)))
            if not len(rows):
                continue
            hi, lo = int(rows[-1]), int(rows[0])  # a place's sightings are chronological
            if newest is None or q.found.key(hi) > newest[0]:
                newest = (q.found.key(hi), q, hi)
            if first is None or q.found.key(lo) < first[0]:
                first = (q.found.key(lo), q, lo)
        if newest is not None and first is not None:
            # seen elsewhere on a later pass, or after it was found missing here: moved
            p.verdict, p.moved_to = "moved", newest[1].index
            since += [(p, "newest_since", newest[1], newest[2]), (p, "seen_since", first[1], first[2])]
        else:  # seen elsewhere only on the pass it was last seen here (another view of it): gone
            p.verdict = "gone"
    top = w.places[0]
    w.status = top.verdict
    if top.verdict != "gone":
        ep, t_last = int(passes[0][-1]), float(top.found.t[-1])
        for q, q_pass in zip(w.places[1:], passes[1:], strict=True):
            later = [h for h in q.revisits if h.memory.t > t_last]
            if later and int(q_pass[-1]) == ep:
                w.status = "gone"
                w.status_note = (
                    f"last seen at {fmt_time(t_last)} from place {top.index} (m{int(top.found.ids[-1])}); "
                    f"on that pass it was also seen from place {q.index} (last m{int(q.found.ids[-1])}), "
                    f"which was looked at again at {fmt_time(later[0].memory.t)} (m{later[0].memory.id}) "
                    "without it"
                )
                break
    return since
