"""Turn what a user types for a time into Unix seconds (UTC).

Accepted forms, tried in this order:
- a number or `+12s` / `+1m30s` / `start+12`: seconds from the start of the recording;
- `HH:MM:SS[.fff]`: a time of day (UTC) on the recording's first day; when that instant lies
  outside the recording but the same clock reading fits as an offset from its start (a 27 s
  clip asked for "00:00:12"), it is read as the offset. `+HH:MM:SS` forces the offset reading;
- ISO 8601 dates/datetimes (`2011-05-10T12:40:30`, with or without a zone; no zone means UTC);
- relative phrases: `10 minutes ago`, `2 h ago`, `yesterday`, `now`, `start`, `end`, relative
  to the latest memory (a robot's "now" is its last observation; for a live robot they agree);
- a bare large number (> 1e8) is taken as Unix seconds.
Nothing here reads the local time zone.
"""

from __future__ import annotations

import math
import numbers
import re
from dataclasses import dataclass
from datetime import datetime, timedelta, timezone

from .errors import InputError
from .types import RANGES, T_MAX, T_MIN

_UNITS = {
    "s": 1.0,
    "sec": 1.0,
    "secs": 1.0,
    "second": 1.0,
    "seconds": 1.0,
    "m": 60.0,
    "min": 60.0,
    "mins": 60.0,
    "minute": 60.0,
    "minutes": 60.0,
    "h": 3600.0,
    "hr": 3600.0,
    "hrs": 3600.0,
    "hour": 3600.0,
    "hours": 3600.0,
    "d": 86400.0,
    "day": 86400.0,
    "days": 86400.0,
}
_DURATION = re.compile(r"^\s*(?:(\d+(?:\.\d+)?)\s*([a-z]+)\s*)+$")
_PART = re.compile(r"(\d+(?:\.\d+)?)\s*([a-z]+)")
_CLOCK = re.compile(r"^(\+)?(\d{1,2}):(\d{2})(?::(\d{2}(?:\.\d+)?))?$")


def fmt_time(t: float) -> str:
    """The one way ravenmem writes a time: ISO 8601 in UTC with milliseconds and a `Z`.

    Tables, JSON, the agent's listings and the models' answers all use it, and `parse_time`
    reads it back exactly (to the millisecond). A time no calendar date can show (a memory
    written before times were checked at the door, `ravenmem.types.check_time`) is shown as
    its number rather than failing the listing it is part of.
    """
    try:
        dt = datetime.fromtimestamp(t, tz=timezone.utc)
    except (OverflowError, OSError, ValueError):
        return f"{t!r} s (no calendar date)"
    return dt.strftime("%Y-%m-%dT%H:%M:%S.%f")[:-3] + "Z"


class TimeRangeError(InputError):
    """A time that resolves outside what a memory can hold (`parse_time`)."""


@dataclass(frozen=True)
class TimeContext:
    """The recording's span, which relative forms are resolved against."""

    start: float
    end: float


def parse_duration(text: str) -> float:
    """`90`, `90s`, `1m30s`, `2 hours`, `00:01:30` -> seconds (finite)."""
    s = text.strip().lower()
    try:
        v = float(s)
    except ValueError:
        pass
    else:
        if not math.isfinite(v):
            raise InputError(f"duration {text!r} is not a finite number of seconds")
        return v
    m = _CLOCK.match(s)
    if m:
        return _clock_seconds(m)
    if _DURATION.match(s):
        total = 0.0
        for num, unit in _PART.findall(s):
            if unit not in _UNITS:
                raise InputError(f"unknown time unit {unit!r} in {text!r}")
            total += float(num) * _UNITS[unit]
        return total
    raise InputError(f"cannot read a duration from {text!r} (try 90, 90s, 1m30s or 00:01:30)")


def _clock_seconds(m: re.Match[str]) -> float:
    h, mi, sec = int(m.group(2)), int(m.group(3)), float(m.group(4) or 0.0)
    if mi >= 60 or sec >= 60:
        raise InputError(f"invalid clock time {m.group(0)!r}")
    return h * 3600.0 + mi * 60.0 + sec


def parse_time(expr: str | float | int, ctx: TimeContext | None) -> float:
    """Resolve a time expression to Unix seconds; `ctx` is needed for relative forms.

    The result is always a time a memory can hold (`ravenmem.types.T_MIN` to `T_MAX`, 1970 to
    2100): `nan`, `inf`, `1e400`, `1e308`, `99999999999 days ago` (and anything that resolves
    to them) are refused with an `InputError` rather than silently matching nothing, or
    everything: this is the one door every time a user gives goes through (search filters,
    `forget`, the HTTP and MCP tools, the agent's tool calls), so no command acts on one.
    """
    t = _parse_time(expr, ctx)
    if not math.isfinite(t):
        raise InputError(f"time {expr!r} is not a finite time")
    # a memory an earlier version let older or later times into (before they were checked at
    # the door) may still be searched from its own `start` or `end`
    lo, hi = (T_MIN, T_MAX) if ctx is None else (min(T_MIN, ctx.start), max(T_MAX, ctx.end))
    if not lo <= t <= hi:
        raise TimeRangeError(f"time {_shown(expr)} is out of range ({RANGES['t']})")
    return t


def named_time(name: str, expr: str | float | int, ctx: TimeContext | None) -> float:
    """`parse_time`, its error naming the option or field the time was given as."""
    try:
        return parse_time(expr, ctx)
    except InputError as e:
        raise InputError(f"{name}: {e}") from None


def _shown(expr: object) -> str:
    text = repr(expr)
    return text if len(text) <= 60 else text[:57] + "..."


def _parse_time(expr: str | float | int, ctx: TimeContext | None) -> float:
    if isinstance(expr, bool) or not isinstance(expr, (str, numbers.Real)):
        raise InputError(f"a time must be a number or a string, got {expr!r}")
    if isinstance(expr, numbers.Real):
        try:
            v = float(expr)
        except OverflowError:
            v = math.inf
        if not math.isfinite(v):
            raise InputError(f"time {expr!r} is not a finite time")
        return _offset_or_epoch(v, ctx, str(expr))
    s = expr.strip().lower()
    if not s:
        raise InputError("empty time expression")
    try:
        v = float(s)
    except ValueError:
        pass
    else:
        if not math.isfinite(v):
            raise InputError(f"time {expr!r} is not a finite time")
        return _offset_or_epoch(v, ctx, expr)
    if s in ("now", "end", "latest"):
        return _need(ctx, expr).end
    if s in ("start", "beginning", "first"):
        return _need(ctx, expr).start
    if s.startswith("start+"):
        return _need(ctx, expr).start + parse_duration(s[len("start+") :])
    m = _CLOCK.match(s)
    if m:
        return _clock(m, _need(ctx, expr))
    if s.startswith("+"):
        return _need(ctx, expr).start + parse_duration(s[1:])
    if s.endswith(" ago"):
        return _need(ctx, expr).end - parse_duration(s[: -len(" ago")])
    if s == "yesterday":
        return _need(ctx, expr).end - 86400.0
    try:
        dt = datetime.fromisoformat(expr.strip().replace("Z", "+00:00"))
    except ValueError:
        dt = None
    if dt is not None:
        if dt.tzinfo is None:
            dt = dt.replace(tzinfo=timezone.utc)
        return dt.timestamp()
    if _DURATION.match(s):
        return _need(ctx, expr).start + parse_duration(s)
    raise InputError(
        f"cannot read a time from {expr!r}: use seconds from start (12, +12s), HH:MM:SS, "
        "an ISO datetime, or '10 minutes ago'"
    )


def _need(ctx: TimeContext | None, expr: object) -> TimeContext:
    if ctx is None:
        raise InputError(f"time {expr!r} is relative to the recording, and the memory is empty")
    return ctx


def _offset_or_epoch(v: float, ctx: TimeContext | None, expr: str) -> float:
    if v > 1e8:  # a Unix timestamp (after 1973): absolute
        return v
    return _need(ctx, expr).start + v


def _clock(m: re.Match[str], ctx: TimeContext) -> float:
    secs = _clock_seconds(m)
    if m.group(1):  # "+HH:MM:SS": always an offset from the start
        return ctx.start + secs
    day = datetime.fromtimestamp(ctx.start, tz=timezone.utc).replace(
        hour=0, minute=0, second=0, microsecond=0
    )
    as_day = (day + timedelta(seconds=secs)).timestamp()
    if ctx.start - 1e-6 <= as_day <= ctx.end + 1e-6:
        return as_day
    if secs <= ctx.end - ctx.start + 1e-6:
        return ctx.start + secs
    return as_day
