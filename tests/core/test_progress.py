"""Progress lines: a total, a percentage, the time so far and an ETA from the pace, at most one
line every few seconds and always the last."""

from __future__ import annotations

from ravenmem.progress import Eta, fmt_seconds


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_eta_from_the_pace_and_throttled() -> None:
    clock, lines = Clock(), []
    eta = Eta(lines.append, "drive", 10, every_s=3.0, clock=clock)
    eta.update(0)
    clock.t += 4.0
    eta.update(2, "red box")  # 2 done in 4 s: 8 left at 2 s each
    clock.t += 1.0
    eta.update(3)  # within 3 s of the last line: not said
    clock.t += 11.0
    eta.update(10)  # the last line is always said
    assert lines == [
        "drive: 0/10 (0%), 0 s elapsed",
        "drive: 2/10 (20%), 4 s elapsed, ETA 16 s; red box",
        "drive: 10/10 (100%), 16 s elapsed, done",
    ]


def test_a_budget_gives_an_upper_bound() -> None:
    clock = Clock()
    eta = Eta(lambda _: None, "explore", 3000, upper=True, clock=clock)
    clock.t += 30.0
    assert eta.line(1000) == "explore: 1000/3000 (33%), 30 s elapsed, ETA at most 1 min 0 s"


def test_seconds_in_words() -> None:
    assert [fmt_seconds(s) for s in (0.4, 59.6, 95, 4000)] == ["0 s", "60 s", "1 min 35 s", "1 h 6 min"]
