"""What `last_seen` answers: the places where a thing was seen, their verdicts, and the thing's
whereabouts (how they are decided: `ravenmem.memory.changes`).

Plain results, shared by the facade, the tools table (`latest` mode), the agent and the
service: each place says its verdict in a sentence (`Place.sentence`) and as plain data
(`Place.as_dict`, the `change` of a hit in `--json`, HTTP and MCP).

A place holds its sightings as arrays (`Sightings`: ids, times, cameras, scores), which is all
the rules look at; the records of the memories an answer shows (its first, last and best
sighting, its revisits) are read when the question is answered, and the rest only when
`Place.sightings` is asked for: a place passed every day for months holds thousands.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field, replace
from typing import Any, Literal

import numpy as np

from ..errors import InputError
from ..store.base import Cameras
from ..timeparse import fmt_time
from ..types import Hit, MemoryRecord, Pose

Verdict = Literal["still there", "moved", "gone", "not revisited"]
VERDICTS: tuple[Verdict, ...] = ("still there", "moved", "gone", "not revisited")


Load = Callable[[Sequence[int], bool], list[MemoryRecord]]  # records still stored (with embeddings?)


@dataclass(frozen=True)
class Sightings:
    """Memories that show the thing, in (time, id) order, as parallel arrays: `ids` (int64),
    `t`, `poses` ((n, 7) as `Cameras.poses`: x, y, yaw, quaternion) and `scores`; `counts` and
    `spans` ((n, 2), NaN where none) say what a consolidated memory stands for."""

    ids: np.ndarray
    t: np.ndarray
    poses: np.ndarray
    scores: np.ndarray
    counts: np.ndarray | None = None
    spans: np.ndarray | None = None

    @classmethod
    def of(cls, cams: Cameras, scores: np.ndarray) -> Sightings:
        """From cameras and their scores, in any order."""
        order = np.lexsort((cams.ids, cams.t))
        return cls(cams.ids[order], cams.t[order], cams.poses[order], np.asarray(scores, np.float64)[order])

    @classmethod
    def none(cls) -> Sightings:
        return cls(np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 7)), np.zeros(0))

    def __len__(self) -> int:
        return len(self.ids)

    @property
    def cameras(self) -> Cameras:
        return Cameras(self.ids, self.t, self.poses)

    def key(self, i: int) -> tuple[float, int]:
        """The (time, id) of row `i`: its place in chronological order."""
        return (float(self.t[i]), int(self.ids[i]))

    def take(self, rows: np.ndarray) -> Sightings:
        """The rows a mask or index array selects (in the order given)."""
        counts = None if self.counts is None else self.counts[rows]
        spans = None if self.spans is None else self.spans[rows]
        return Sightings(self.ids[rows], self.t[rows], self.poses[rows], self.scores[rows], counts, spans)

    def union(self, more: Sightings) -> Sightings:
        """These and the memories of `more` not among them, chronological."""
        if not len(more):
            return self
        after = len(self) > 0 and more.key(0) > self.key(-1)  # a place's later sightings: appended
        new = more if after else more.take(~among(more.ids, self.ids))
        if not len(self):
            return new
        both = Sightings(
            np.concatenate([self.ids, new.ids]),
            np.concatenate([self.t, new.t]),
            np.concatenate([self.poses, new.poses]),
            np.concatenate([self.scores, new.scores]),
        )
        return both if after else both.take(np.lexsort((both.ids, both.t)))

    def grouped(self, groups: dict[int, tuple[int, float, float]]) -> Sightings:
        """With `counts` and `spans` from consolidated groups (rep -> count, first_t, last_t)."""
        counts, spans = np.ones(len(self), np.int64), np.full((len(self), 2), np.nan)
        for row, i in enumerate(self.ids.tolist()):
            g = groups.get(i)
            if g is not None:
                counts[row], spans[row] = g[0], (g[1], g[2])
        return Sightings(self.ids, self.t, self.poses, self.scores, counts, spans)


def read_rows(
    wanted: Sequence[tuple[Place, Sequence[int]]], extra: Sequence[int] = ()
) -> dict[int, MemoryRecord]:
    """Read the records of several places' rows not read yet with one store call (what an
    answer shows: each place's first, last and best sighting, where it was seen since), and
    those of the `extra` ids with their embeddings (revisits, scored from them); returns the
    latter."""
    owners: dict[int, list[Place]] = {}
    for p, rows in wanted:
        for r in rows:
            i = int(p.found.ids[r])
            if i not in p._records:
                owners.setdefault(i, []).append(p)
    load = next((p.load for p, _ in wanted if p.load is not None), None)
    if load is None or not (owners or extra):
        return {}
    got = {r.id: r for r in load([*owners, *(i for i in extra if i not in owners)], bool(extra))}
    for i, held in owners.items():
        if i in got:
            rec = got[i] if got[i].embedding is None else replace(got[i], embedding=None)
            for p in held:
                p._records[i] = rec
    return {i: got[i] for i in extra if i in got}


def among(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per id of `a`, whether it is one of `b`: a search in `b` sorted (`np.isin` costs ten
    times as much on a few hundred ids, and a question asked it a dozen times)."""
    if not len(b):
        return np.zeros(len(a), bool)
    ref = np.sort(b)
    return ref[np.minimum(np.searchsorted(ref, a), len(ref) - 1)] == a


@dataclass(eq=False)
class Place:
    """One place where the thing was seen, and what later visits say about it. `found` holds
    its sightings as arrays (chronological); `sightings` are they as hits with their records,
    read from the memory when first asked for (the first, last and best sighting's records are
    read with the answer). `revisits` (views of the place without the thing, after the robot
    looked away; at most `max_revisits` kept: the first ones and the latest) are
    chronological."""

    index: int
    found: Sightings
    revisits: list[Hit] = field(default_factory=list)
    revisit_count: int = 0
    later_visit: bool = False
    verdict: Verdict = "not revisited"
    moved_to: int | None = None  # moved: the place of its newest sighting since
    seen_since: Hit | None = None  # moved: the first sighting elsewhere since
    newest_since: Hit | None = None  # moved: the newest sighting elsewhere since
    load: Load | None = field(default=None, repr=False)  # reads records (None: none read)
    _records: dict[int, MemoryRecord] = field(default_factory=dict, init=False, repr=False)
    _hits: list[Hit] | None = field(default=None, init=False, repr=False)

    def read(self, rows: Sequence[int]) -> None:
        """Read the records of `found`'s `rows` not read yet (one store call)."""
        try:
            read_rows([(self, rows)])
        except InputError as e:  # the memory was closed since the question
            raise InputError(
                f"{e}: a place's sightings are read from the memory when first asked for; "
                "ask before closing it (Place.found holds them as arrays)"
            ) from None

    def record(self, row: int) -> MemoryRecord:
        """The record of `found`'s row `row`; the camera alone if it was forgotten meanwhile."""
        i = int(self.found.ids[row])
        if i not in self._records:
            self.read([row])
        got = self._records.get(i)
        if got is None:  # forgotten since the question: what the arrays know of it
            x, y, yaw, *q = self.found.poses[row].tolist()
            got = MemoryRecord(id=i, t=float(self.found.t[row]), pose=Pose(x, y, 0.0, yaw, _quat(q)))
        return got

    def hit(self, row: int) -> Hit:
        """`found`'s row `row` as a hit with its record."""
        f = self.found
        count = int(f.counts[row]) if f.counts is not None else 1
        span = None
        if f.spans is not None and not math.isnan(f.spans[row, 0]):
            span = (float(f.spans[row, 0]), float(f.spans[row, 1]))
        return Hit(memory=self.record(row), score=float(f.scores[row]), count=count, span=span)

    @property
    def sightings(self) -> list[Hit]:
        """Every sighting with its record, chronological: read from the memory at the first
        ask, so ask while it is open. A memory another process forgot since is left out."""
        if self._hits is None:
            self.read(range(len(self.found)))
            held = [r for r, i in enumerate(self.found.ids.tolist()) if i in self._records]
            self._hits = [self.hit(r) for r in held]
        return self._hits

    def newest(self, k: int) -> list[Hit]:
        """The newest `k` sightings, newest first (only their records read)."""
        rows = list(range(len(self.found) - 1, max(-1, len(self.found) - 1 - k), -1))
        self.read(rows)
        return [self.hit(r) for r in rows]

    @property
    def first(self) -> MemoryRecord:
        return self.record(0)

    @property
    def last(self) -> MemoryRecord:
        return self.record(len(self.found) - 1)

    @property
    def last_hit(self) -> Hit:
        """The last sighting as a hit."""
        return self.hit(len(self.found) - 1)

    @property
    def best_row(self) -> int:
        """The row of the best-scored sighting (the earliest of equals)."""
        return int(np.argmax(self.found.scores))

    @property
    def best(self) -> Hit:
        return self.hit(self.best_row)

    @property
    def seen(self) -> int:
        """How many memories showed it here: a consolidated sighting counts what it stands for."""
        f = self.found
        return int(f.counts.sum()) if f.counts is not None else len(f)

    @property
    def first_t(self) -> float:
        """When it was first seen here (a consolidated sighting's span starts earlier than its t)."""
        f = self.found
        return float(
            (f.t if f.spans is None else np.where(np.isnan(f.spans[:, 0]), f.t, f.spans[:, 0])).min()
        )

    @property
    def last_t(self) -> float:
        """When it was last seen here (a consolidated sighting's span ends later than its t)."""
        f = self.found
        return float(
            (f.t if f.spans is None else np.where(np.isnan(f.spans[:, 1]), f.t, f.spans[:, 1])).max()
        )

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
            shown = [(p.last_hit, "sighting")]
            if p.verdict in ("moved", "gone"):
                views = p.revisits[:1] + (p.revisits[-1:] if len(p.revisits) > 1 else [])
                shown += [(h, "revisit") for h in views[:revisits]]
            for h, role in shown:
                change = {**info, "role": role}
                out.append(
                    ChangeHit(memory=h.memory, score=h.score, count=h.count, span=h.span, change=change)
                )
        return out


def _quat(q: list[float]) -> tuple[float, float, float, float] | None:
    """A quaternion from a camera row (None where it has none: NaN)."""
    return None if any(math.isnan(v) for v in q) else (q[0], q[1], q[2], q[3])
