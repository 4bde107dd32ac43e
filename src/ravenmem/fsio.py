"""Crash-safe file writes: one way to replace a file, used by every part of ravenmem.

A writer gets a temporary file in the target's folder; on success the data is flushed and
fsynced, the temporary file is renamed over the target and the folder is fsynced, so a crash at
any point leaves either the old file or the new one, never a mix. On an exception the
temporary file is removed and the target is untouched.
"""

from __future__ import annotations

import json
import os
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any


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


def is_temp_file(path: Path) -> bool:
    """True for a temporary file `atomic_open` leaves behind when the process is killed."""
    return path.name.startswith(".") and path.name.endswith(".tmp")
