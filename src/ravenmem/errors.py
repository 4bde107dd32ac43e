"""Errors a user can act on. The CLI prints `error: <message>` for these and exits non-zero;
anything else is a bug and keeps its traceback."""

from __future__ import annotations


class RavenmemError(Exception):
    """Base class: the message names the problem (file, line, field) in one line."""


class InputError(RavenmemError):
    """Bad user input: a missing file, a malformed line, an unknown option value."""


class EmbedderMismatchError(RavenmemError):
    """A memory was opened with an embedder other than the one that built it."""


class EmptyMemoryError(RavenmemError):
    """A query needs memories and the memory has none."""


class MemoryBusyError(RavenmemError):
    """Another process (or another Memory object) holds the memory's writer lock (ravenmem.memory.lock)."""


class StoreUnavailableError(RavenmemError):
    """A store server (Milvus) cannot be reached or refused the connection."""


class MissingDependencyError(RavenmemError):
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
