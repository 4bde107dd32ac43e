"""ravenmem: a long-term visuo-spatio-temporal memory for robots.

import ravenmem
mem = ravenmem.open("./desk.mem")
hits = mem.search_text("a computer keyboard", k=5)
"""

from __future__ import annotations

import importlib as _importlib
import typing as _typing

if _typing.TYPE_CHECKING:
    from .agent import Agent
    from .memory import Memory, create, open
    from .types import Filter, Frame, Hit, MemoryRecord, Pose, Region

__version__ = "0.1.0"
__all__ = ["Agent", "Filter", "Frame", "Hit", "Memory", "MemoryRecord", "Pose", "Region", "create", "open"]

# the public API, imported when first used: `ravenmem --help` (which imports this package)
# needs no memory code, and the agent pulls in the OpenAI client
_WHERE = {"Agent": ".agent", "Memory": ".memory", "create": ".memory", "open": ".memory"} | {
    name: ".types" for name in ("Filter", "Frame", "Hit", "MemoryRecord", "Pose", "Region")
}


def __getattr__(name: str) -> _typing.Any:
    if name in _WHERE:
        value = getattr(_importlib.import_module(_WHERE[name], __name__), name)
        globals()[name] = value  # found once; later uses are plain attribute reads
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:  # the public API only (not the submodules this file imported)
    return sorted([*__all__, "__version__"])
