"""One writer per memory folder: an exclusive lock that the OS releases when its holder dies.

Two processes appending to one memory would hand out the same ids (the store counts them in
memory) and delete each other's temporary files, so a memory has at most one writer at a time.
The lock is `flock` on `writer.lock` inside the memory folder: the kernel drops it when the
holder exits or is killed (kill -9 included), so a crash never leaves a memory locked and there
is no stale-pid guessing. The holder writes its pid, command and start time into the file only
so that a second writer can say who holds it. Readers (search, info, ask) never take it.

`flock` locks belong to an open file, not to a process: a second `WriterLock` on the same folder
in the same process is refused too, which is what keeps two `Memory` objects from writing one
folder. On systems without `fcntl` (Windows) no lock is taken.
"""

from __future__ import annotations

import contextlib
import json
import os
import shlex
import sys
import time
from pathlib import Path

from ..errors import MemoryBusyError
from ..timeparse import fmt_time
from .folder import LOCK

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX
    fcntl = None  # type: ignore[assignment]

__all__ = ["WriterLock"]


def _command(limit: int = 200, part: int = 60) -> str:
    """The holder's command line, short enough for one message line and still telling: the
    program by its file name (a venv's path says nothing), each long argument cut in its middle
    (its start and end tell most), and past `limit` the middle arguments left out rather than the
    first and last ones (what runs, and on what). Bounded however long the checkout's path."""
    argv = list(getattr(sys, "orig_argv", None) or [sys.executable, *sys.argv]) or ["python"]
    words = [Path(argv[0]).name or argv[0], *(_middle(a, part) for a in argv[1:])]
    words = [shlex.quote("".join(c if c.isprintable() else " " for c in w)) for w in words]
    if len(" ".join(words)) <= limit:
        return " ".join(words)
    head, tail = words[:1], words[1:]  # the program and its first arguments, up to a third
    while tail and len(" ".join([*head, tail[0]])) <= limit // 3:
        head.append(tail.pop(0))
    kept: list[str] = []  # then the last arguments, as many as fit
    while tail and len(" ".join([*head, "...", tail[-1], *kept])) <= limit:
        kept.insert(0, tail.pop())
    return " ".join([*head, "...", *kept])


def _middle(text: str, most: int) -> str:
    """`text` with its middle replaced by '...' when longer than `most` characters."""
    if len(text) <= most:
        return text
    keep = most - 3
    return text[: keep // 2] + "..." + text[len(text) - (keep - keep // 2) :]


class WriterLock:
    """The writer lock of one memory folder (see the module docstring)."""

    def __init__(self, folder: str | os.PathLike[str]) -> None:
        self.folder = Path(folder)
        self.path = self.folder / LOCK
        self._fd: int | None = None

    @property
    def held(self) -> bool:
        return self._fd is not None

    def acquire(self, wait: bool | float = False) -> None:
        """Take the lock. `wait=False` fails at once, `True` waits as long as it takes, a number
        waits up to that many seconds; a refusal raises MemoryBusyError naming the holder."""
        if self._fd is not None:
            return
        if fcntl is None:  # pragma: no cover
            return
        if isinstance(wait, bool):
            deadline = float("inf") if wait else 0.0
        else:
            deadline = float(wait)
            if not deadline >= 0:
                raise ValueError(f"wait: expected True, False or seconds >= 0, got {wait!r}")
        deadline += time.monotonic()
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o644)
        pause = 0.05
        try:
            while True:
                try:
                    fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
                    break
                except BlockingIOError:
                    if time.monotonic() >= deadline:
                        raise MemoryBusyError(self._busy_message(wait)) from None
                    time.sleep(min(pause, max(deadline - time.monotonic(), 0.0)))
                    pause = min(pause * 2, 0.5)
        except BaseException:
            os.close(fd)
            raise
        info = {"pid": os.getpid(), "command": _command(), "since": time.time()}
        os.ftruncate(fd, 0)
        os.pwrite(fd, (json.dumps(info) + "\n").encode(), 0)
        self._fd = fd

    def release(self) -> None:
        """Give the lock up (closing the file releases it; the file itself stays, harmless)."""
        fd, self._fd = self._fd, None
        if fd is not None:
            try:
                os.ftruncate(fd, 0)  # no holder any more: nobody to name
            finally:
                os.close(fd)  # releases the flock

    def holder(self) -> dict[str, object]:
        """What the current holder wrote about itself ({} when nothing readable)."""
        try:
            data = json.loads(self.path.read_text(encoding="utf-8"))
        except (OSError, ValueError):
            return {}
        return data if isinstance(data, dict) else {}

    def _busy_message(self, wait: bool | float) -> str:
        h = self.holder()
        pid = h.get("pid")
        who = "another process"
        if pid == os.getpid():
            who = "another Memory object in this process (close it first)"
        elif pid is not None:
            who = f"pid {pid}"
            if h.get("command"):
                who += f" ({h['command']})"
            since = h.get("since")
            if isinstance(since, (int, float)):
                who += f" since {fmt_time(float(since))}"
        waited = f" after waiting {float(wait):g} s" if wait and not isinstance(wait, bool) else ""
        return (
            f"memory {self.folder} is being written by {who}{waited}; one writer at a time "
            "(searching it is fine): wait with `ingest --wait` (Python: wait=True) or stop that process"
        )

    def __del__(self) -> None:
        if self._fd is not None:
            with contextlib.suppress(OSError):
                os.close(self._fd)
