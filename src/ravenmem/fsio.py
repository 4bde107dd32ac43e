"""Crash-safe file writes: one way to replace a file, used by every part of ravenmem.

A writer gets a temporary file in the target's folder; on success the data is flushed and
fsynced, the temporary file is renamed over the target and the folder is fsynced, so a crash at
any point leaves either the old file or the new one, never a mix. On an exception the
temporary file is removed and the target is untouched.

Reads are bounded too: `read_bounded` is the one way ravenmem reads a whole file a user names
(pose tracks, TUM lists, configs, Nav2 maps, question and label files), so `/dev/zero` or a
10 GB file is a one-line error naming the file and the limit after reading at most the limit.
A write that finds the disk full is `DiskFullError` (`disk_full`), one line wherever it happens.

A killed writer leaves its temporary file behind (`.NAME.<12 hex>.tmp`). The writer holds an
exclusive `flock` on it while it writes, which the OS drops when the process dies, so
`remove_stale_temp_files` can tell a leftover from a file another process is writing right now.
"""

from __future__ import annotations

import errno
import functools
import json
import logging
import os
import re
import sqlite3
import stat
import time
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any, ParamSpec, TypeVar
from urllib.parse import quote

try:
    import fcntl
except ImportError:  # pragma: no cover - not POSIX: temp files are then never reported stale
    fcntl = None  # type: ignore[assignment]

from .errors import InputError, RavenmemError

P = ParamSpec("P")
R = TypeVar("R")
_log = logging.getLogger(__name__)
_TEMP_NAME = re.compile(r"\..+\.[0-9a-f]{12}\.tmp")

MAX_TEXT = 64 << 20  # a list, a table or a question file: 64 MiB (a pose track of 500,000 rows is 40)
MAX_CONFIG = 1 << 20  # a settings file: 1 MiB
MAX_IMAGE = 256 << 20  # a picture file sent to a service: 256 MiB (40 MP raw is 120)
_FULL = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)  # no space, a quota, a file-size limit (ulimit -f)


class DiskFullError(RavenmemError, OSError):
    """A write found no space left (or a quota or file-size limit); nothing acknowledged is lost,
    and reads go on. HTTP 507."""


def disk_full(e: BaseException) -> DiskFullError | None:
    """`e` as a one-line DiskFullError when it (or what caused it) is "no space left", else None:
    SQLite says `database or disk is full` (or a write error: a quota, a file-size limit), the
    OS says ENOSPC (EDQUOT, EFBIG)."""
    seen: BaseException | None = e
    while seen is not None:
        if isinstance(seen, DiskFullError):
            return seen
        if isinstance(seen, OSError) and seen.errno in _FULL:
            where = f" writing {seen.filename}" if seen.filename else ""
            return DiskFullError(f"disk full{where} ({os.strerror(seen.errno)}); nothing stored was lost")
        name = getattr(seen, "sqlite_errorname", "")
        if name == "SQLITE_FULL" or "database or disk is full" in str(seen):
            return DiskFullError(
                "disk full: the store cannot grow (SQLite: database or disk is full); nothing stored was lost"
            )
        if name in ("SQLITE_IOERR_WRITE", "SQLITE_IOERR_FSYNC", "SQLITE_IOERR_TRUNCATE"):
            # what SQLite says when a write fails with EFBIG (a file-size limit) or EDQUOT
            return DiskFullError(
                f"disk full or failing: the store cannot write (SQLite: {seen}); nothing stored was lost"
            )
        seen = seen.__cause__ or seen.__context__
    return None


def sqlite_reader(path: str | os.PathLike[str]) -> sqlite3.Connection:
    """A connection that reads a WAL-mode SQLite database and writes nothing in its folder.

    While a writer is at work (its `-wal` file is there) a read-only connection (`mode=ro`)
    shares the writer's files. On a database at rest a read-only connection would create the
    `-wal` and `-shm` files and leave them behind, so a normal connection is opened with
    `query_only` set: its close removes the two files it created (an empty WAL: the database
    file itself is untouched). Where those files cannot be made (read-only media, an archive,
    another user's memory, a full disk) the database is read as it is, `immutable=1` (no locks,
    no files), unless a writer's `-wal` and `-shm` are both there to be read with it. Usable
    from any thread (callers serialise access)."""
    p = Path(path)
    wal, shm = Path(f"{p}-wal"), Path(f"{p}-shm")
    if not os.access(p.parent, os.W_OK) or _free_bytes(p.parent) < 1 << 20:
        if wal.exists() and shm.exists():
            conn = _probe(_open_reader(p, "mode=ro"))
            if conn is not None:
                return conn
        return _immutable(p, wal)
    if wal.exists():
        conn = _probe(_open_reader(p, "mode=ro"))
        return conn if conn is not None else _immutable(p, wal)
    conn = sqlite3.connect(p, check_same_thread=False, isolation_level=None, timeout=30.0)
    conn.execute("PRAGMA query_only=1")
    probed = _probe(conn)
    return probed if probed is not None else _immutable(p, wal)


def _free_bytes(folder: Path) -> int:
    """Bytes this process may still write in `folder`'s file system (a lot when unknown)."""
    try:
        st = os.statvfs(folder)
    except (OSError, AttributeError):
        return 1 << 62
    return st.f_bavail * st.f_frsize


# what SQLite says when the -wal or -shm cannot be created or mapped (no space, no permission)
_CANNOT_SHARE = ("SQLITE_IOERR", "SQLITE_CANTOPEN", "SQLITE_FULL", "SQLITE_READONLY")


def _probe(conn: sqlite3.Connection) -> sqlite3.Connection | None:
    """`conn` after a first read (which creates or maps the -wal and -shm files), or None
    (closed) when those files cannot be had; other errors are raised."""
    try:
        conn.execute("SELECT COUNT(*) FROM sqlite_master").fetchone()
        return conn
    except sqlite3.OperationalError as e:
        conn.close()
        if not str(getattr(e, "sqlite_errorname", "")).startswith(_CANNOT_SHARE):
            raise
        return None


def _immutable(p: Path, wal: Path) -> sqlite3.Connection:
    if wal.exists() and wal.stat().st_size > 0:
        _log.warning(
            "%s: the writes in its -wal file cannot be read here (its -shm cannot be made or "
            "mapped: a read-only folder or a full disk); reading the database as last checkpointed",
            p,
        )
    return _open_reader(p, "mode=ro&immutable=1")


def _open_reader(p: Path, mode: str) -> sqlite3.Connection:
    uri = f"file:{quote(str(p.resolve()))}?{mode}"
    conn = sqlite3.connect(uri, uri=True, check_same_thread=False, isolation_level=None, timeout=30.0)
    conn.execute("PRAGMA query_only=1")
    return conn


PICTURE_TAG = ("Software", "ravenmem")  # the PNG text chunk every picture ravenmem writes carries


def is_our_picture(path: str | os.PathLike[str]) -> bool:
    """Whether `path` is a PNG ravenmem wrote (its `Software` text chunk says so): the only kind
    of existing file a picture output may replace."""
    try:
        with open(path, "rb") as f:
            head = f.read(1 << 16)
    except OSError:
        return False
    key, value = (v.encode() for v in PICTURE_TAG)
    return head.startswith(b"\x89PNG\r\n\x1a\n") and b"tEXt" + key + b"\x00" + value in head


def rollback(conn: sqlite3.Connection) -> None:
    """Undo a connection's open transaction, if there still is one: a COMMIT that failed on a
    full disk has already rolled back, and a second error would hide the first."""
    if conn.in_transaction:
        conn.execute("ROLLBACK")


@contextmanager
def write_transaction(conn: sqlite3.Connection) -> Iterator[None]:
    """One write transaction: BEGIN IMMEDIATE (the write lock taken up front, so two writers
    queue instead of failing half-way), COMMIT when the block ends, and on any error (a
    KeyboardInterrupt included) the rollback that leaves the rows as they were, then the error."""
    conn.execute("BEGIN IMMEDIATE")
    try:
        yield
        conn.execute("COMMIT")
    except BaseException:
        rollback(conn)
        raise


def reports_full_disk(fn: Callable[P, R]) -> Callable[P, R]:
    """`fn` (a write) with a full disk raised as one `DiskFullError`, whatever raised it (SQLite,
    a thumbnail, the manifest): callers and front ends see one line, "disk full ..."."""

    @functools.wraps(fn)
    def write(*args: P.args, **kwargs: P.kwargs) -> R:
        try:
            return fn(*args, **kwargs)
        except DiskFullError:
            raise
        except Exception as e:
            full = disk_full(e)
            if full is None:
                raise
            raise full from e

    return write


def read_bounded(path: str | os.PathLike[str], limit: int = MAX_TEXT, what: str = "file") -> bytes:
    """The bytes of `path`, at most `limit` of them: a larger file, or a device that never ends
    (`/dev/zero`), is a one-line `InputError` naming the file and the limit once `limit + 1`
    bytes were read. A folder, a FIFO or a socket is refused before it is opened (opening a
    FIFO would wait for a writer)."""
    p = Path(path)
    try:
        st = p.stat()
    except FileNotFoundError:
        raise InputError(f"{what} {p} does not exist") from None
    except OSError as e:
        raise InputError(f"{what} {p} cannot be read ({e.strerror or e})") from None
    if stat.S_ISDIR(st.st_mode):
        raise InputError(f"{what} {p} is a folder, not a file")
    if stat.S_ISFIFO(st.st_mode) or stat.S_ISSOCK(st.st_mode):
        raise InputError(f"{what} {p} is not a regular file")
    if stat.S_ISREG(st.st_mode) and st.st_size > limit:
        raise InputError(
            f"{what} {p} is larger than the limit of {size_text(limit)} ({size_text(st.st_size)})"
        )
    try:
        with open(p, "rb") as f:
            data = f.read(limit + 1)
    except OSError as e:
        raise InputError(f"{what} {p} cannot be read ({e.strerror or e})") from None
    if len(data) > limit:
        raise InputError(f"{what} {p} is larger than the limit of {size_text(limit)}")
    return data


def read_text(
    path: str | os.PathLike[str], limit: int = MAX_TEXT, what: str = "file", errors: str = "strict"
) -> str:
    """`read_bounded` decoded as UTF-8 (a byte-order mark is dropped); invalid UTF-8 is a
    one-line `InputError` unless `errors="replace"`."""
    data = read_bounded(path, limit, what)
    try:
        return data.decode("utf-8-sig", errors=errors)
    except UnicodeDecodeError as e:
        raise InputError(f"{what} {path}: not UTF-8 text (byte {e.start})") from None


def size_text(n: int) -> str:
    """A size as people read it (`512 MiB`, `12.5 KiB`): limits, and what a command freed."""
    for unit in ("bytes", "KiB", "MiB", "GiB"):
        if n < 1024 or unit == "GiB":
            return f"{n:g} {unit}" if unit == "bytes" else f"{n:.4g} {unit}"
        n /= 1024  # type: ignore[assignment]
    return str(n)


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


def move(src: str | os.PathLike[str], dest: str | os.PathLike[str]) -> None:
    """Rename a file within its folder, durably (a file set aside, e.g. by crash recovery)."""
    os.replace(src, dest)
    fsync_dir(Path(dest).parent)


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
