"""Which time zone a NaVQA data.csv's clock times are written in, read from the data itself.

data.csv gives each answer as a wall-clock time ("7:59:00") in the zone of the machine that
wrote it (the ReMEmbR release's UTC-8, the RAVEN release's UTC-5), while each question's clip
(`qa_unfilled.json` / `human_qa.json` start_time..end_time) and every CODa frame file are Unix
seconds. The zone is the one UTC offset that puts the truth times inside their clips: each
whole-hour offset from UTC-12 to UTC+14 is tried and the rows it fits are counted. A few rows
that no offset fits are the annotators' slips (the published data.csv files have 5 of 110),
and stay named truth errors (one of them may fit another offset by chance). The data disagrees
with itself when the best offset fits no more than half the rows, or another offset fits more
than one row in ten (two clocks wrote the file); then nothing is guessed.
"""

from __future__ import annotations

import re
from collections.abc import Iterable
from dataclasses import dataclass
from datetime import datetime, time, timedelta, timezone, tzinfo
from zoneinfo import ZoneInfo, ZoneInfoNotFoundError

from ...errors import InputError

MARGIN_S = 3.0  # a truth this close outside its recording still counts as inside (the releases' 3 s captions)
OFFSETS_H = range(-12, 15)  # the whole-hour offsets tried (a half-hour zone is given with --tz)


def parse_zone(text: str) -> tzinfo:
    """'UTC-5', 'UTC+05:30', '-05:00' or an IANA name such as America/Chicago."""
    m = re.fullmatch(r"\s*(?:UTC|GMT)?\s*([+-])(\d{1,2})(?::?(\d{2}))?\s*", text, re.I)
    if m:
        sign = -1 if m.group(1) == "-" else 1
        return timezone(sign * timedelta(hours=int(m.group(2)), minutes=int(m.group(3) or 0)))
    if text.strip().upper() in ("UTC", "GMT", "Z"):
        return timezone.utc
    try:
        return ZoneInfo(text.strip())
    except (ZoneInfoNotFoundError, ValueError) as e:
        raise InputError(
            f"--tz: unknown time zone {text!r} (give e.g. UTC-5 or America/Chicago) ({e})"
        ) from e


def zone_label(zone: tzinfo) -> str:
    if isinstance(zone, ZoneInfo):
        return zone.key
    off = zone.utcoffset(None)
    assert off is not None
    hours, rest = divmod(int(off.total_seconds()), 3600)
    return "UTC" if not off else f"UTC{hours:+d}" + (f":{abs(rest) // 60:02d}" if rest else "")


def offset_zone(hours: int) -> tzinfo:
    return timezone(timedelta(hours=hours))


def parse_clock(part: str, where: str) -> time:
    """'7:59:00' -> a time of day; anything else is a one-line error naming the row."""
    try:
        return datetime.strptime(part.strip(), "%H:%M:%S").time()
    except ValueError:
        raise InputError(f"{where}: timestamp {part.strip()!r} is not H:MM:SS") from None


def clock_times(stamp: str, where: str) -> list[time]:
    """'7:59:00' or '07:56:38,07:59:00' (a duration's two ends) -> times of day."""
    return [parse_clock(p, where) for p in stamp.split(",") if p.strip()]


def clock_instant(hms: time, zone: tzinfo, near: float) -> float:
    """Unix seconds of the clock time `hms` in `zone` on the day that puts it nearest `near`
    (a recording that runs past midnight keeps its late clock times on the right day)."""
    day = datetime.fromtimestamp(near, zone).date()
    cands = [datetime.combine(day + timedelta(days=k), hms, tzinfo=zone).timestamp() for k in (-1, 0, 1)]
    return min(cands, key=lambda c: abs(c - near))


def inside(t: float, t0: float, t1: float) -> bool:
    return t0 - MARGIN_S <= t <= t1 + MARGIN_S


@dataclass(frozen=True)
class Sample:
    """One data.csv row's clock times and the clip (Unix seconds) they must fall inside."""

    clocks: tuple[time, ...]
    t0: float
    t1: float

    def fits(self, zone: tzinfo) -> bool:
        mid = 0.5 * (self.t0 + self.t1)
        return all(inside(clock_instant(c, zone, mid), self.t0, self.t1) for c in self.clocks)


@dataclass(frozen=True)
class Inferred:
    """What the data says about its zone: the zone (None when it cannot say), why, and the
    refusal to show when a clock time must be read and the zone is None."""

    zone: tzinfo | None
    why: str
    refusal: str = ""


def infer_zone(samples: Iterable[Sample], what: str) -> Inferred:
    """The one whole-hour offset that puts the most truth times inside their clips (see the
    module docstring); `what` names the file in the messages."""
    rows = list(samples)
    if not rows:
        return Inferred(None, "", f"{what}: no timed row has a clip to infer its time zone from")
    counts = {o: sum(s.fits(offset_zone(o)) for s in rows) for o in OFFSETS_H}
    ranked = sorted(counts, key=lambda o: (-counts[o], abs(o)))
    best, second = ranked[0], ranked[1]
    n, k = len(rows), counts[best]
    tally = ", ".join(f"UTC{o:+d}: {counts[o]}" for o in ranked[:3] if counts[o]) or "none"
    if 2 * k <= n or counts[second] > max(1, n // 10):
        return Inferred(
            None,
            "",
            f"{what}: the data disagrees with itself about its time zone (of {n} timed rows, these fit "
            f"their clips under each offset: {tally}): give --tz",
        )
    left = f"; under it {n - k} fall outside their clips, each a named truth error" if k < n else ""
    return Inferred(
        offset_zone(best),
        f"inferred from the data: UTC{best:+d} puts {k} of {n} data.csv truth times inside their "
        f"clips ({tally}){left}",
    )
