"""Does anything support this search? The verdict `ask --offline` declines by, on search hits.

A search always lists its k best memories, even when the thing is not in the memory at all:
"a potted plant" on a desk recording still returns four hits, a little above zero. The offline
reasoner (`ravenmem.agent.offline`) knows better: it scores the thing as it scores any question's
subject (paraphrased, fused with OCR, a hit's score capped by its neighbours in time) and calls it
found only when that support reaches above the threshold calibrated on decoys, things that are
not there. Search results carry that same verdict per hit (`Hit.supported`, `supported` in the
JSON of the CLI, HTTP, MCP and ROS), computed by the reasoner itself: one rule, not two.
"""

from __future__ import annotations

import threading
from dataclasses import replace

from ..memory.protocol import MemoryLike
from ..types import Hit
from .offline import OfflineReasoner

__all__ = ["Judge", "judged"]


class Judge:
    """Marks text hits as supported or not for one memory. Keeps its reasoner, so the decoys'
    calibration is computed once per memory (a server holds one Judge for its life), and again
    when a live memory has doubled (or halved) since: what decoys reach depends on what is there.
    A served memory's questions borrow that calibration (`lend`): one threshold for both."""

    def __init__(self, memory: MemoryLike) -> None:
        self.memory = memory
        self.reasoner = OfflineReasoner(memory)
        self._count = memory.count()
        self._lock = threading.Lock()  # callers at once (a robot's services) wait for one calibration

    def current(self) -> OfflineReasoner:
        """The reasoner, calibrated on the memory as it is now (within a factor of two)."""
        with self._lock:
            n = self.memory.count()
            if not self._count / 2 <= n <= 2 * self._count:
                self.reasoner, self._count = OfflineReasoner(self.memory), n
            self.reasoner.threshold()
            return self.reasoner

    def mark(self, query: str, hits: list[Hit]) -> list[Hit]:
        """`hits` with `supported` set: the hit's support for `query` above the threshold
        (a hit outside the reasoner's scored pool is not supported)."""
        if not hits:
            return hits
        support, threshold = self.current().support(query)
        return [replace(h, supported=support.get(h.memory.id, float("-inf")) > threshold) for h in hits]

    def lend(self, method: object) -> None:
        """Give `method`, when it is an offline reasoner of this memory with the default
        settings (the one a question builds), this Judge's calibration instead of its own."""
        if isinstance(method, OfflineReasoner) and method.memory is self.memory and self.memory.count() > 0:
            method.adopt_calibration(self.current())


def judged(memory: MemoryLike, query: str, hits: list[Hit]) -> list[Hit]:
    """`Judge(memory).mark(query, hits)`: one search's verdicts."""
    return Judge(memory).mark(query, hits)
