"""Consolidation: merge runs of near-duplicate memories into one that keeps their span and count.

A robot parked in one place, or sweeping past one shelf, stores many memories that look alike.
Consolidation walks each source's memories in time order and merges *neighbours in time* (never
two visits of a place at different times, so "when was the mug last seen there" survives) that
are taken close together (the merged run fits in a `max_distance` metres box) and look alike
(cosine of the runs' count-weighted mean embeddings). Pairs merge most similar first, until
no neighbouring pair is more similar than `max_similarity` and, with a `budget`, until at most
`budget` memories remain.

Each merged run keeps one stored memory, its *representative*: the member whose embedding is
closest to the run's mean (the medoid under cosine to the mean), so the kept picture, pose and
time are a real observation from the middle of the run. How many memories it stands for and
the first and last time they were seen go to the sidecar table (`ravenmem.memory.groups`);
the search tools report them as `count` and `span`. The other members are forgotten the way
`forget` does it, with the same crash safety (see `groups` for the two-phase protocol).
"""

from __future__ import annotations

import heapq
import math
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import numpy as np

from ...errors import InputError
from ...fsio import reports_full_disk
from ...types import MemoryRecord
from ..core import Core
from ..folder import file_size, thumb_file
from ..groups import exists
from ..writer import Writer
from .forget import journal_entries


@dataclass
class ConsolidateReport:
    """What `consolidate` merged (or, with `dry_run`, would merge)."""

    before: int
    after: int
    merged: int = 0
    groups: int = 0
    represented: int = 0
    lowest_similarity: float | None = None
    budget: int | None = None
    budget_met: bool | None = None
    max_similarity: float | None = None
    max_distance: float = 1.0
    thumbnails: int = 0
    thumbnail_bytes: int = 0
    store_bytes_est: int = 0
    dry_run: bool = False

    def as_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["bytes_freed"] = self.thumbnail_bytes + self.store_bytes_est
        if out["max_distance"] == math.inf:
            out["max_distance"] = None
        return out


@dataclass
class Plan:
    """Runs to merge: for each, the representative's index, the other members' indices, and
    the (count, first_t, last_t) the representative will stand for."""

    reps: list[int]
    drops: list[list[int]]
    groups: list[tuple[int, float, float]]
    lowest: float | None
    entries_after: int


def check_options(
    budget: int | None, max_similarity: float | None, max_distance: float, max_gap: float | None
) -> None:
    if budget is None and max_similarity is None:
        raise InputError("consolidate: give --budget N (memories to keep) or --max-similarity S")
    if budget is not None and (isinstance(budget, bool) or not isinstance(budget, int) or budget < 1):
        raise InputError(f"--budget: expected a whole number >= 1, got {budget!r}")
    if max_similarity is not None and not (-1.0 <= float(max_similarity) <= 1.0):
        raise InputError(f"--max-similarity: expected a cosine from -1 to 1, got {max_similarity!r}")
    if not (max_distance > 0) or math.isnan(max_distance):
        raise InputError(f"--max-distance: expected metres > 0 (or inf), got {max_distance!r}")
    if max_gap is not None and (not (max_gap >= 0) or math.isnan(max_gap)):
        raise InputError(f"--max-gap: expected seconds >= 0, got {max_gap!r}")


def plan(
    t: np.ndarray,
    xy: np.ndarray,
    source: np.ndarray,
    emb: np.ndarray,
    counts: np.ndarray,
    spans: np.ndarray,
    budget: int | None = None,
    max_similarity: float | None = None,
    max_distance: float = 1.0,
    max_gap: float | None = None,
) -> Plan:
    """Greedy agglomeration of time-neighbours (see the module docstring).

    Inputs are parallel over entries: time, (x, y), a source code, unit embeddings, how many
    memories each entry already stands for and its (first, last) span. Returns indices into them.
    """
    n = len(t)
    order = np.lexsort((t, source))
    pos = np.empty(n, np.int64)
    pos[order] = np.arange(n)
    e = emb[order].astype(np.float32)
    w = counts[order].astype(np.float32)
    sums = e * w[:, None]
    norms = np.linalg.norm(sums, axis=1)
    src = source[order]
    lo = xy[order].copy()
    hi = xy[order].copy()
    first = spans[order, 0].copy()
    last = spans[order, 1].copy()
    members: list[list[int]] = [[i] for i in range(n)]
    nxt = np.arange(1, n + 1)
    prv = np.arange(-1, n - 1)
    alive = np.ones(n, bool)
    version = np.zeros(n, np.int64)
    heap: list[tuple[float, int, int, int, int]] = []

    def push(a: int, b: int) -> None:
        if a < 0 or b >= n or src[a] != src[b]:
            return
        if max_gap is not None and first[b] - last[a] > max_gap:
            return
        box = np.maximum(hi[a], hi[b]) - np.minimum(lo[a], lo[b])
        if math.hypot(float(box[0]), float(box[1])) > max_distance:
            return
        den = float(norms[a] * norms[b])
        sim = float(sums[a] @ sums[b]) / den if den > 0 else -1.0
        heapq.heappush(heap, (-sim, a, b, int(version[a]), int(version[b])))

    for i in range(n - 1):
        push(i, i + 1)
    left, lowest = n, None
    while heap:
        neg, a, b, va, vb = heapq.heappop(heap)
        if not (alive[a] and alive[b]) or version[a] != va or version[b] != vb:
            continue
        sim = -neg
        over = budget is not None and left > budget
        similar = max_similarity is not None and sim > max_similarity
        if not (over or similar):  # the best pair left is not worth merging: nor is any other
            break
        # merge b (the later run) into a
        members[a].extend(members[b])
        members[b] = []
        sums[a] += sums[b]
        norms[a] = np.linalg.norm(sums[a])
        lo[a], hi[a] = np.minimum(lo[a], lo[b]), np.maximum(hi[a], hi[b])
        first[a], last[a] = min(first[a], first[b]), max(last[a], last[b])
        alive[b] = False
        version[a] += 1
        nxt[a] = nxt[b]
        if nxt[b] < n:
            prv[nxt[b]] = a
        left -= 1
        lowest = sim if lowest is None else min(lowest, sim)
        push(int(prv[a]), a)
        push(a, int(nxt[a]))
    reps: list[int] = []
    drops: list[list[int]] = []
    groups: list[tuple[int, float, float]] = []
    for a in np.flatnonzero(alive).tolist():
        m = members[a]
        if len(m) < 2:
            continue
        mean = sums[a] / (norms[a] or 1.0)
        rep = m[int(np.argmax(e[m] @ mean))]
        reps.append(int(order[rep]))
        drops.append([int(order[i]) for i in m if i != rep])
        groups.append((int(w[m].sum()), float(first[a]), float(last[a])))
    return Plan(reps, drops, groups, lowest, left)


class Consolidation(Core):
    """`Memory.consolidate`."""

    @reports_full_disk
    def consolidate(
        self,
        budget: int | None = None,
        max_similarity: float | None = None,
        max_distance: float = 1.0,
        max_gap: float | None = None,
        dry_run: bool = False,
    ) -> ConsolidateReport:
        """Merge runs of near-duplicate memories (neighbours in time, within `max_distance`
        metres, most similar first) into one representative that keeps their count and time
        span, until no neighbours are more similar than `max_similarity` and/or at most
        `budget` memories remain. Crash-safe like `forget`; see
        `ravenmem.memory.lifelong.consolidate`.
        """
        check_options(budget, max_similarity, max_distance, max_gap)
        writer = None if dry_run else self.writer()
        ids = self.store.select()
        n = len(ids)
        report = ConsolidateReport(
            before=n,
            after=n,
            budget=budget,
            max_similarity=max_similarity,
            max_distance=max_distance,
            dry_run=dry_run,
        )
        known = self.groups()
        report.represented = n + sum(known[i][0] - 1 for i in ids.tolist() if i in known)
        if n < 2:
            report.budget_met = budget is None or n <= budget
            return report
        recs = []
        for s in range(0, n, 20_000):
            recs += self.store.get(ids[s : s + 20_000].tolist(), with_embeddings=True)
        t = np.array([r.t for r in recs], np.float64)
        xy = np.array([(r.pose.x, r.pose.y) for r in recs], np.float64)
        codes: dict[str, int] = {}
        source = np.array([codes.setdefault(r.source, len(codes)) for r in recs], np.int64)
        emb = np.stack([r.embedding for r in recs if r.embedding is not None]).astype(np.float32)
        counts = np.array([known.get(r.id, (1, r.t, r.t))[0] for r in recs], np.int64)
        spans = np.array([known.get(r.id, (1, r.t, r.t))[1:] for r in recs], np.float64)
        p = plan(t, xy, source, emb, counts, spans, budget, max_similarity, max_distance, max_gap)
        drop_idx = sorted(i for d in p.drops for i in d)
        report.after = p.entries_after
        report.merged = len(drop_idx)
        report.groups = len(p.reps)
        report.lowest_similarity = p.lowest
        report.budget_met = None if budget is None else p.entries_after <= budget
        stats = self.store.stats()
        per_mem = float(stats.get("bytes") or 0) / n  # type: ignore[arg-type]
        report.store_bytes_est = round(per_mem * len(drop_idx))
        thumbs = [
            (pth, recs[i]) for i in drop_idx if (pth := thumb_file(self.path, recs[i].image_path)) is not None
        ]
        report.thumbnail_bytes = sum(file_size(pth) for pth, _ in thumbs)
        report.thumbnails = sum(1 for pth, _ in thumbs if pth.is_file())
        if writer is None or not drop_idx:
            return report
        drop = np.array(sorted(recs[i].id for i in drop_idx), np.int64)
        rows = [(recs[r].id, *g) for r, g in zip(p.reps, p.groups)]
        _apply(self, writer, drop, rows, thumbs)
        return report


def _apply(
    mem: Core,
    writer: Writer,
    drop: np.ndarray,
    rows: list[tuple[int, int, float, float]],
    thumbs: list[tuple[Path, MemoryRecord]],
) -> None:
    """Journal the thumbnails, record the groups (pending), delete, commit, settle."""
    journal = writer.journal(journal_entries(mem.path, thumbs))
    table = writer.group_table()
    try:
        batch = table.begin(rows, drop)
        try:
            with writer.change(groups=True):
                mem.store.delete(drop)
        except BaseException:
            if exists(mem.store, int(drop[0])):
                table.abort(batch)
            else:
                table.commit(batch)
            raise
        table.commit(batch)
    finally:
        table.close()
    if journal is not None:
        writer.settle(mem.store, journal)
    writer.deleted(drop, groups=False)
