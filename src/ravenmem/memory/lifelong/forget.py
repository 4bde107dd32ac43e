"""Forgetting: remove memories (store rows, index entries, thumbnails, sidecar rows) for good.

The order makes a killed `forget` leave the old state or the new one:

1. the thumbnails of the memories to forget are listed in a thumbnail journal
   (`ravenmem.memory.recovery`, the same journal ingest writes);
2. the store deletes the memories in one transaction (`Store.delete`);
3. the journal is settled: the listed thumbnails no stored memory references are deleted;
4. rows of the forgotten memories go from the sidecars (the groups table).

Killed before 2 commits, every memory and thumbnail is still there (the next writer finds the
journal, sees the thumbnails referenced and keeps them); killed after, the memories are gone
and the next writer deletes the thumbnails left over. Sidecar rows of forgotten ids are never
shown (ids never repeat) and are pruned by the next writer. Every step goes through the
writer handle (`ravenmem.memory.writer`).

Relative times (`+3600`, `10 minutes ago`) are resolved once, before anything is deleted,
against the span of everything the memory has ever held (the manifest's `span_seen`, saved
before the delete), not against what is left: the same command run again, or again after a
kill, resolves to the same instant and removes nothing more. The report gives the instants used.
"""

from __future__ import annotations

import math
from collections.abc import Iterable
from dataclasses import asdict, dataclass, replace
from pathlib import Path
from typing import Any

import numpy as np

from ...errors import InputError
from ...fsio import reports_full_disk
from ...timeparse import TimeContext, fmt_time, named_time
from ...types import MemoryRecord
from ..core import Core
from ..folder import file_size, thumb_file
from ..protocol import Near, TimeLike
from ..recovery import Entry


@dataclass
class ForgetReport:
    """What `forget` removed (or, with `dry_run`, would remove)."""

    removed: int
    t_first: float | None = None
    t_last: float | None = None
    thumbnails: int = 0
    thumbnail_bytes: int = 0
    store_bytes_est: int = 0
    unknown_ids: int = 0
    memories_left: int = 0
    dry_run: bool = False
    before_t: float | None = None  # the instants `before` and `after` resolved to
    after_t: float | None = None

    @property
    def bytes_freed(self) -> int:
        return self.thumbnail_bytes + self.store_bytes_est

    def as_dict(self) -> dict[str, Any]:
        out = asdict(self)
        out["bytes_freed"] = self.bytes_freed
        out["first_time"] = fmt_time(self.t_first) if self.t_first is not None else None
        out["last_time"] = fmt_time(self.t_last) if self.t_last is not None else None
        out["before_time"] = fmt_time(self.before_t) if self.before_t is not None else None
        out["after_time"] = fmt_time(self.after_t) if self.after_t is not None else None
        return out


def parse_ids(text: str) -> list[int]:
    """`"3,7,10-12"` -> [3, 7, 10, 11, 12]; a one-line InputError for anything else."""
    out: list[int] = []
    for part in text.replace(" ", "").split(","):
        if not part:
            continue
        lo, sep, hi = part.partition("-")
        try:
            a = int(lo)
            b = int(hi) if sep else a
        except ValueError:
            raise InputError(f"--ids: expected ids such as 3,7,10-12, got {part!r}") from None
        if a < 0 or b < a:
            raise InputError(f"--ids: {part!r} is not an id or an increasing range of ids >= 0")
        if b - a >= 10_000_000:
            raise InputError(f"--ids: the range {part!r} is too long (at most 10,000,000 ids)")
        out.extend(range(a, b + 1))
    if not out:
        raise InputError("--ids: no id given")
    return out


def select(
    mem: Core,
    before: float | None = None,
    after: float | None = None,
    region: Near | None = None,
    ids: Iterable[int] | None = None,
) -> tuple[np.ndarray, int]:
    """The ids every given selector accepts (sorted) and how many of `ids` are not stored;
    `before` and `after` are resolved instants (Unix seconds, see `clock`)."""
    if before is None and after is None and region is None and ids is None:
        raise InputError("forget: say what to forget: --before T, --after T, --region x,y,r or --ids ...")
    want: np.ndarray | None = None
    if ids is not None:
        vals = list(ids)
        for v in vals:
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 0:
                raise InputError(f"ids: expected memory ids (whole numbers >= 0), got {v!r}")
        want = np.unique(np.asarray(vals, np.int64))
    if mem.count() == 0:  # nothing to forget (and no recording for relative times to refer to)
        return np.empty(0, np.int64), 0 if want is None else len(want)
    filt = replace(mem.make_filter(near=region), after=after, before=before)
    chosen = mem.store.select(None if filt.empty else filt)
    if want is None:
        return np.asarray(chosen, np.int64), 0
    stored = want[np.isin(want, mem.store.select())] if not filt.empty else want[np.isin(want, chosen)]
    return np.asarray(chosen[np.isin(chosen, want)], np.int64), len(want) - len(stored)


class Forgetting(Core):
    """`Memory.forget`."""

    @reports_full_disk
    def forget(
        self,
        before: TimeLike = None,
        after: TimeLike = None,
        region: Near | None = None,
        ids: Iterable[int] | None = None,
        dry_run: bool = False,
    ) -> ForgetReport:
        """Remove memories for good: store rows, index entries, thumbnails, sidecar rows.

        Selectors combine (a memory must match every one given): `before`/`after` are time
        expressions (inclusive, as in the search filters), `region` an (x, y, radius m) disc,
        `ids` memory ids. At least one is required; selecting nothing is not an error (the
        report says 0). Crash-safe: a killed process leaves all of them or none, and the next
        writer removes any thumbnail left over (`ravenmem.memory.lifelong.forget`). Takes the
        writer lock; `dry_run=True` only reports what would go.
        """
        writer = None if dry_run else self.writer()
        before_t = after_t = None
        if before is not None or after is not None:  # checked before anything is written
            ctx = self.clock(save=False) if self.count() else None
            before_t = None if before is None else named_time("before", before, ctx)
            after_t = None if after is None else named_time("after", after, ctx)
            if ctx is not None and not dry_run:
                self.clock(save=True)
        chosen, unknown = select(self, before_t, after_t, region, ids)
        stats = self.store.stats()
        n_before = int(stats.get("count") or 0)  # type: ignore[call-overload]
        per_mem = float(stats.get("bytes") or 0) / n_before if n_before else 0.0  # type: ignore[arg-type]
        report = ForgetReport(
            removed=0,
            unknown_ids=unknown,
            memories_left=n_before,
            dry_run=dry_run,
            before_t=before_t,
            after_t=after_t,
        )
        if len(chosen) == 0:
            return report
        thumbs: list[tuple[Path, MemoryRecord]] = []
        t_lo, t_hi = math.inf, -math.inf
        for s in range(0, len(chosen), 50_000):
            for r in self.store.get(chosen[s : s + 50_000].tolist()):
                t_lo, t_hi = min(t_lo, r.t), max(t_hi, r.t)
                p = thumb_file(self.path, r.image_path)
                if p is not None:
                    thumbs.append((p, r))
        report.t_first, report.t_last = t_lo, t_hi
        report.thumbnail_bytes = sum(file_size(p) for p, _ in thumbs)
        report.thumbnails = sum(1 for p, _ in thumbs if p.is_file())
        if writer is None:
            report.removed = len(chosen)
            report.store_bytes_est = round(per_mem * len(chosen))
            report.memories_left = n_before - len(chosen)
            return report
        journal = writer.journal(journal_entries(self.path, thumbs))
        with writer.change():
            report.removed = self.store.delete(chosen)
        if journal is not None:
            report.thumbnails = writer.settle(self.store, journal)
        writer.deleted(chosen)
        report.store_bytes_est = round(per_mem * report.removed)
        report.memories_left = self.count()
        return report

    def clock(self, save: bool) -> TimeContext:
        """What forget's relative times are resolved against: the span of everything this
        memory has held, i.e. what it holds now and the manifest's `span_seen`, which is saved
        (`save`, under the writer lock) before anything is deleted."""
        lo, hi = self.time_span()
        seen = self.manifest.span_seen
        if seen:
            lo, hi = min(lo, seen[0]), max(hi, seen[1])
        if save and seen != [lo, hi]:
            with self.writer().change():
                self.manifest.span_seen = [lo, hi]
                self.manifest.save(self.path)
        return TimeContext(lo, hi)


def journal_entries(folder: Path, thumbs: list[tuple[Path, MemoryRecord]]) -> list[Entry]:
    """The journal's lines for thumbnails about to be deleted with their memories."""
    return [(p.relative_to(folder).as_posix(), r.source, int(r.frame_index), float(r.t)) for p, r in thumbs]
