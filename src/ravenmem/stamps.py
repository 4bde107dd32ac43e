"""Seconds as ROS 2 time stamps, in one place (a goal's header, a reply's time, a restamped
goal): `builtin_interfaces/Time` is whole seconds and nanoseconds, the nanoseconds rounded and
never reaching a full second."""

from __future__ import annotations

import math


def sec_nanosec(t: float) -> dict[str, int]:
    """{"sec", "nanosec"} of `t` seconds (finite, >= 0)."""
    sec = int(math.floor(t))
    return {"sec": sec, "nanosec": min(int(round((t - sec) * 1e9)), 999_999_999)}
