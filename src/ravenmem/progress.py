"""Progress lines with a total and an ETA, for work that reports through a `say(str)` callback
(the demo, exploration): one line at most every few seconds, and the last one always, so that a
long phase is never silent and a log stays short. Bars on a terminal are tqdm's (ingest)."""

from __future__ import annotations

import time
from collections.abc import Callable


def fmt_seconds(s: float) -> str:
    """12.3 -> '12 s', 95 -> '1 min 35 s', 4000 -> '1 h 7 min'."""
    s = max(0.0, s)
    if s < 60:
        return f"{s:.0f} s"
    if s < 3600:
        return f"{int(s // 60)} min {int(s % 60)} s"
    return f"{int(s // 3600)} h {int(s % 3600 // 60)} min"


class Eta:
    """`label: done/total (pct%), elapsed ..., ETA ...` through `say`.

    `upper=True` says the total is a budget that the work may stop short of (an exploration
    that runs out of frontiers), so the ETA is printed as an upper bound."""

    def __init__(
        self,
        say: Callable[[str], None],
        label: str,
        total: int,
        every_s: float = 3.0,
        upper: bool = False,
        clock: Callable[[], float] = time.perf_counter,
    ) -> None:
        self.say, self.label, self.total, self.every_s, self.upper = say, label, max(0, total), every_s, upper
        self.clock = clock
        self.t0 = clock()
        self._last: float | None = None

    def line(self, done: int, note: str = "") -> str:
        """The progress line for `done` of the total (the ETA from the pace so far)."""
        elapsed = self.clock() - self.t0
        parts = [f"{self.label}: {done}/{self.total}"]
        if self.total:
            parts[0] += f" ({100 * min(done, self.total) / self.total:.0f}%)"
        timing = f"{fmt_seconds(elapsed)} elapsed"
        if 0 < done < self.total:
            left = elapsed / done * (self.total - done)
            timing += f", ETA {'at most ' if self.upper else ''}{fmt_seconds(left)}"
        elif done >= self.total:
            timing += ", done"
        return f"{parts[0]}, {timing}" + (f"; {note}" if note else "")

    def update(self, done: int, note: str = "", force: bool = False) -> None:
        """Say the line when `every_s` passed since the last one, at the end, or when forced."""
        now = self.clock()
        if force or done >= self.total or self._last is None or now - self._last >= self.every_s:
            self._last = now
            self.say(self.line(done, note))
