"""Crash-safe file writes: one way to replace a file, used by every part of ravenmem.

A writer gets a temporary file in the target's folder; on success the data is flushed and
fsynced, the temporary file is renamed over the target and the folder is fsynced, so a crash at
any point leaves either the old file or the new one, never a mix. On an exception the
temporary file is removed and the target is untouched.

A killed writer leaves its temporary file behind (`.NAME.<12 hex>.tmp`). The writer holds an
exclusive `flock` on it while it writes, which the OS drops when the process dies, so
`remove_stale_temp_files` can tell a leftover from a file another process is writing right now.
"""

from __future__ import annotations

import json
import os
import re
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX: temp files are then never reported stale
    fcntl = None  # type: ignore[assignment]

_TEMP_NAME = re.compile(r"\..+\.[0-9a-f]{12}\.tmp")


def fsync_dir(folder: str | os.PathLike[str]) -> None:
    """Make a rename in `folder` durable (POSIX); a no-op where folders cannot be opened."""
    try:
        fd = os.open(folder, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


@contextmanager
def atomic_open(
    path: str | os.PathLike[str], mode: str = "wb", encoding: str | None = None
) -> Iterator[IO[Any]]:
    """Open a temporary file that replaces `path` when the block ends without an exception.

    `mode` is a write mode ("wb", "w", "w+b"); text modes default to UTF-8.
    """
    target = Path(path)
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = target.with_name(f".{target.name}.{uuid.uuid4().hex[:12]}.tmp")
    if "b" not in mode and encoding is None:
        encoding = "utf-8"
    f = open(tmp, mode, encoding=encoding)  # noqa: SIM115 - closed below on every path
    if fcntl is not None:
        fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)  # "in use" until closed or killed
    try:
        yield f
        f.flush()
        os.fsync(f.fileno())
        f.close()
        os.replace(tmp, target)
    except BaseException:
        f.close()
        tmp.unlink(missing_ok=True)
        raise
    fsync_dir(target.parent)


def atomic_write(path: str | os.PathLike[str], data: bytes | str) -> None:
    """Replace `path` with `data` (bytes, or text written as UTF-8), crash-safely."""
    with atomic_open(path, "wb" if isinstance(data, bytes) else "w") as f:
        f.write(data)


def atomic_write_json(path: str | os.PathLike[str], obj: Any, **dumps: Any) -> None:
    """Replace `path` with `obj` as JSON (keyword arguments go to `json.dumps`), crash-safely."""
    atomic_write(path, json.dumps(obj, **dumps))


def publish_dir(tmp: str | os.PathLike[str], final: str | os.PathLike[str]) -> None:
    """Give a folder built under a temporary name (`tmp`, next to `final`) its final name, once
    complete: a crash before leaves no `final`, after leaves the whole folder. The files inside
    should be written with `atomic_write*` (fsynced); the rename itself is made durable here.
    `final` must not exist (an `OSError` otherwise, and `tmp` is left as it was)."""
    src, dest = Path(tmp), Path(final)
    if dest.exists():
        raise FileExistsError(f"{dest} already exists")
    os.rename(src, dest)
    fsync_dir(dest.parent)


def is_temp_file(path: Path) -> bool:
    """True for a name `atomic_open` gives its temporary files (`.NAME.<12 hex>.tmp`)."""
    return _TEMP_NAME.fullmatch(path.name) is not None


def remove_stale_temp_files(
    folder: str | os.PathLike[str], min_age: float = 2.0, target: str = "", wait: bool = False
) -> list[Path]:
    """Delete the temporary files killed writers left in `folder` (not recursive); return them.
    `target` limits it to the temporary files of one file name (e.g. "index.faiss").

    Only files named like `atomic_open`'s that no process holds locked (a killed writer's lock
    is gone) and that are older than `min_age` seconds (the instant between creating a file and
    locking it) are removed: never another running process's file, never anything else.
    `min_age=0` (for a caller that holds the writer lock over files only the writer writes):
    any age, even a timestamp ahead of this machine's clock.

    `wait=True` is for a writer cleaning up after a crash: the files still too young are
    checked again once they are `min_age` old (one sleep of at most `min_age`, only when there
    are such files), so a writer killed an instant before this call leaves nothing behind
    either. Young files are never probed: taking the lock of a file whose writer is between
    creating and locking it would make that writer fail.
    """
    removed, youngest = _sweep(folder, min_age, target)
    if wait and youngest is not None:
        time.sleep(min(max(min_age - youngest, 0.0), min_age))
        removed += _sweep(folder, min_age, target)[0]
    return removed


def _sweep(folder: str | os.PathLike[str], min_age: float, target: str) -> tuple[list[Path], float | None]:
    """One pass of `remove_stale_temp_files`: the files removed, and the age in seconds of the
    youngest temporary file left alone for its age (None when there was none)."""
    removed: list[Path] = []
    youngest: float | None = None
    if fcntl is None:  # pragma: no cover
        return removed, youngest
    try:
        entries = list(os.scandir(folder))
    except OSError:
        return removed, youngest
    now = time.time()
    for e in entries:
        p = Path(e.path)
        if not is_temp_file(p) or not p.name.startswith(f".{target}") or not e.is_file(follow_symlinks=False):
            continue
        try:
            age = now - e.stat(follow_symlinks=False).st_mtime
            if min_age > 0 and age < min_age:
                youngest = age if youngest is None else min(youngest, age)
                continue
            with open(p, "rb") as f:
                try:
                    fcntl.flock(f.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
                except BlockingIOError:
                    continue  # a live writer holds it
                p.unlink()
                removed.append(p)
        except OSError:
            continue
    return removed, youngest
