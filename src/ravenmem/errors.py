"""Errors a user can act on. The CLI prints `error: <message>` for these and exits non-zero;
anything else is a bug and keeps its traceback.

Each is also the built-in exception it is a kind of, so code that knows nothing of ravenmem
catches them as it would Python's own: bad input is a `ValueError`, a memory folder that is not
there a `FileNotFoundError`, an unknown memory id a `LookupError`, a busy writer lock a
`BlockingIOError`, an unreachable server a `ConnectionError`, a missing extra an `ImportError`.
"""

from __future__ import annotations


class RavenmemError(Exception):
    """Base class: the message names the problem (file, line, field) in one line."""


class InputError(RavenmemError, ValueError):
    """Bad user input: a missing file, a malformed line, an unknown option value."""


class MemoryNotFoundError(InputError, FileNotFoundError):
    """A path given as a memory holds none: it does not exist, or has no manifest."""


class NotFoundError(InputError, LookupError):
    """A memory id (or another named thing) that the memory does not hold; HTTP 404."""


class EmbedderMismatchError(RavenmemError, ValueError):
    """A memory was opened with an embedder other than the one that built it."""


class EmptyMemoryError(RavenmemError, LookupError):
    """A query needs memories and the memory has none."""


class MemoryBusyError(RavenmemError, BlockingIOError):
    """Another process (or another Memory object) holds the memory's writer lock
    (ravenmem.memory.lock)."""


class StoreUnavailableError(RavenmemError, ConnectionError):
    """A store server (Milvus) cannot be reached or refused the connection."""


class MissingDependencyError(RavenmemError, ImportError):
    """An optional extra is not installed; the message says which `pip install` fixes it."""


def require(module: str, extra: str) -> object:
    """Import an optional module or raise a clear error naming the extra that provides it."""
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError as e:  # pragma: no cover - exercised when extras are absent
        raise MissingDependencyError(
            f"{module} is not installed: pip install 'ravenmem[{extra}]' ({e})"
        ) from e


def one_line(e: object) -> str:
    """`str(e)` with every run of whitespace (the newlines of a library's multi-line message:
    rcl's argument errors, a hub's HTTP reply) made one space, so that it fits the one-line
    `error: ...` the CLI prints, a service reply's reason and a log line."""
    return " ".join(str(e).split())
