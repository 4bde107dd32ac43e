"""ravenmem: a long-term visuo-spatio-temporal memory for robots.

import ravenmem
mem = ravenmem.open("./desk.mem")
hits = mem.search_text("a computer keyboard", k=5)
"""

import typing as _typing

from .memory import Memory, create, open
from .types import Filter, Frame, Hit, MemoryRecord, Pose, Region

__version__ = "0.1.0"
__all__ = ["Agent", "Filter", "Frame", "Hit", "Memory", "MemoryRecord", "Pose", "Region", "create", "open"]


def __getattr__(name: str) -> _typing.Any:
    if name == "Agent":  # the agent pulls in the OpenAI client: import it only when asked for
        from .agent import Agent

        return Agent
    raise AttributeError(name)


def __dir__() -> list[str]:  # the public API only (not the submodules this file imported)
    return sorted([*__all__, "__version__"])
