"""What `last_seen` answers: the places where a thing was seen, their verdicts, and the thing's
whereabouts (how they are decided: `ravenmem.memory.changes`).

Plain results, shared by the facade, the tools table (`latest` mode), the agent and the
service: each place says its verdict in a sentence (`Place.sentence`) and as plain data
(`Place.as_dict`, the `change` of a hit in `--json`, HTTP and MCP).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Literal

from ..timeparse import fmt_time
from ..types import Hit, MemoryRecord

Verdict = Literal["still there", "moved", "gone", "not revisited"]
VERDICTS: tuple[Verdict, ...] = ("still there", "moved", "gone", "not revisited")


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
            shown = [(p.sightings[-1], "sighting")]
            if p.verdict in ("moved", "gone"):
                views = p.revisits[:1] + (p.revisits[-1:] if len(p.revisits) > 1 else [])
                shown += [(h, "revisit") for h in views[:revisits]]
            for h, role in shown:
                change = {**info, "role": role}
                out.append(
                    ChangeHit(memory=h.memory, score=h.score, count=h.count, span=h.span, change=change)
                )
        return out
