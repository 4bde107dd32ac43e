from datetime import datetime, timezone

import pytest

from ravenmem.errors import InputError
from ravenmem.timeparse import TimeContext, parse_duration, parse_time

# A 27 s recording starting 2011-05-10 12:40:29.5 UTC (the TUM desk clip's clock).
START = datetime(2011, 5, 10, 12, 40, 29, 500000, tzinfo=timezone.utc).timestamp()
CTX = TimeContext(START, START + 27.0)


@pytest.mark.parametrize(
    "expr,expected",
    [
        ("12", START + 12),
        (12, START + 12),
        ("+12s", START + 12),
        ("start+1m", START + 60),
        ("00:00:12", START + 12),  # outside the day's span but fits as an offset
        ("+00:00:05", START + 5),
        ("12:40:40", datetime(2011, 5, 10, 12, 40, 40, tzinfo=timezone.utc).timestamp()),
        ("2011-05-10T12:40:35Z", datetime(2011, 5, 10, 12, 40, 35, tzinfo=timezone.utc).timestamp()),
        ("2011-05-10T14:40:35+02:00", datetime(2011, 5, 10, 12, 40, 35, tzinfo=timezone.utc).timestamp()),
        ("2011-05-10 12:40:35", datetime(2011, 5, 10, 12, 40, 35, tzinfo=timezone.utc).timestamp()),
        ("10 seconds ago", START + 17),
        ("1 min ago", START + 27 - 60),
        ("now", START + 27),
        ("start", START),
        ("1305031230.5", 1305031230.5),
    ],
)
def test_parse_time_forms(expr, expected):
    assert parse_time(expr, CTX) == pytest.approx(expected, abs=1e-6)


def test_naive_iso_is_utc_whatever_the_local_zone(monkeypatch):
    import time

    monkeypatch.setenv("TZ", "America/New_York")
    time.tzset()
    try:
        assert parse_time("2011-05-10T12:40:35", CTX) == pytest.approx(
            datetime(2011, 5, 10, 12, 40, 35, tzinfo=timezone.utc).timestamp()
        )
    finally:
        monkeypatch.delenv("TZ")
        time.tzset()


@pytest.mark.parametrize("expr", ["", "tomorrowish", "12:75:00", "5 parsecs ago"])
def test_bad_times_are_clear_errors(expr):
    with pytest.raises(InputError):
        parse_time(expr, CTX)


def test_relative_needs_a_recording():
    with pytest.raises(InputError, match="empty"):
        parse_time("10 minutes ago", None)
    assert parse_time("2011-05-10T12:40:35Z", None) > 0


def test_durations():
    assert parse_duration("1m30s") == 90
    assert parse_duration("00:01:30") == 90
    assert parse_duration("2 hours") == 7200
    with pytest.raises(InputError):
        parse_duration("soon")


@pytest.mark.parametrize(
    "expr",
    ["1e400", "nan", "-inf", "inf", float("nan"), float("inf"), 10**400, "start+inf", "nan ago", "+nan"],
)
def test_non_finite_times_are_refused(expr):
    with pytest.raises(InputError, match="finite"):
        parse_time(expr, CTX)


def test_numbers_of_any_numeric_type():
    import numpy as np

    assert parse_time(np.int64(12), CTX) == parse_time(np.float32(12.0), CTX) == START + 12
    with pytest.raises(InputError, match="number or a string"):
        parse_time([12], CTX)  # type: ignore[arg-type]
    with pytest.raises(InputError, match="number or a string"):
        parse_time(True, CTX)


@pytest.mark.parametrize(
    "expr",
    [
        "1e308",
        -1e12,
        "-1e308",
        1e12,
        "99999999999 days ago",
        "9999-12-31T00:00:00Z",
        "0001-01-01",
        "-5000000000",
    ],
)
def test_times_no_memory_can_hold_are_refused(expr):
    """One range for every time a user gives (`ravenmem.types.T_MIN`..`T_MAX`), stored or not."""
    with pytest.raises(InputError, match="out of range"):
        parse_time(expr, CTX)


def test_the_range_ends_are_times():
    assert parse_time("4102444800", CTX) == 4102444800.0
    assert parse_time("1970-01-01T00:00:00Z", CTX) == 0.0
