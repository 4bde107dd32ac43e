"""The decoy calibration is shared, not repeated: the decoys' vectors are embedded once per
embedder, a recalibration is only the searches, and a served memory's questions borrow the
search verdicts' calibration. None of it may change a verdict or an answer."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

import ravenmem
from ravenmem.agent.offline import DECOYS, OfflineReasoner
from ravenmem.agent.support import Judge
from ravenmem.memory.folder import OFFLINE_CALIBRATION
from ravenmem.runtime.ask import AskArgs
from ravenmem.runtime.service import Service, ServiceConfig
from tests.agent.conftest import scene_frames
from tests.conftest import ColorEmbedder


class CountingEmbedder(ColorEmbedder):
    """ColorEmbedder that notes every batch of texts it embeds."""

    def __init__(self) -> None:
        self.batches: list[list[str]] = []

    def embed_texts(self, texts: Sequence[str]) -> np.ndarray:
        self.batches.append(list(texts))
        return super().embed_texts(texts)

    def decoy_batches(self) -> int:
        return sum(1 for b in self.batches if DECOYS[0] in b)


class WithoutVectors:
    """The memory as a `MemoryLike` that cannot search by vector: the reasoner embeds the
    decoys and searches them by text, as it always did (the reference to compare with)."""

    def __init__(self, mem: Any) -> None:
        self._mem = mem

    def __getattr__(self, name: str) -> Any:
        if name == "search_vectors":
            raise AttributeError(name)
        return getattr(self._mem, name)


def test_a_second_calibration_does_not_embed_the_decoys_again(tmp_path: Path) -> None:
    frames = scene_frames()
    emb = CountingEmbedder()
    with ravenmem.create(tmp_path / "m.mem", embedder=emb, ocr=False) as mem:
        mem.add_frames(frames[:6])
        first = OfflineReasoner(mem)
        first.threshold()
        assert emb.decoy_batches() == 1
        mem.add_frames(frames[6:])  # the memory changed: the next reasoner calibrates again
        assert (mem.path / OFFLINE_CALIBRATION).is_file()
        second = OfflineReasoner(mem)
        calls = len(emb.batches)
        thr = second.threshold("a red thing")
        assert second._decoy_support is not None and second._decoy_support != first._decoy_support
        assert len(emb.batches) == calls and emb.decoy_batches() == 1  # searches only

        # the same numbers as a reasoner that embeds the decoys and searches them by text
        (mem.path / OFFLINE_CALIBRATION).unlink()
        reference = OfflineReasoner(WithoutVectors(mem))  # type: ignore[arg-type]
        assert reference.threshold("a red thing") == thr
        assert reference._decoy_support == second._decoy_support
        assert emb.decoy_batches() == 2
        for query in ("red", "magenta", "an elephant", "a blue thing"):
            assert second.support(query) == reference.support(query), query


def test_verdicts_and_answers_match_a_fresh_reasoner(tmp_path: Path) -> None:
    """A Judge that recalibrated from cached vectors marks hits as a fresh reasoner would, and a
    service's offline question (the Judge's calibration lent) answers as `ask` alone does."""
    frames = scene_frames()
    emb = CountingEmbedder()
    with ravenmem.create(tmp_path / "m.mem", embedder=emb, ocr=False) as mem:
        mem.add_frames(frames[:4])
        judge = Judge(mem)
        judge.mark("red", mem.search_text("red", k=2))
        mem.add_frames(frames[4:])  # past twice the memories: the Judge calibrates again
        queries = ("red", "magenta", "a smell of toast", "an elephant", "where did I see blue?")
        for query in queries:
            hits = mem.search_text(query, k=5)
            support, thr = OfflineReasoner(WithoutVectors(mem)).support(query)  # type: ignore[arg-type]
            fresh = [support.get(h.memory.id, float("-inf")) > thr for h in hits]
            assert [h.supported for h in judge.mark(query, hits)] == fresh, query
        assert emb.decoy_batches() == 2  # the Judge's two calibrations embedded them once

        svc = Service(mem, ServiceConfig(writable=False))
        svc.search(*_text_search("red"))
        lent = svc.judge().current()._decoy_support
        questions = ("where did I see red?", "is there an elephant?", "when did I last see blue?")
        wanted = {q: OfflineReasoner(mem).ask(q) for q in questions}
        (mem.path / OFFLINE_CALIBRATION).unlink()  # a question calibrating on its own would write it
        for question in questions:
            got = svc.ask(AskArgs(question=question, method="offline")).answer
            want = wanted[question]
            assert (got.found, got.text, got.position, [e.id for e in got.evidence]) == (
                want.found,
                want.text,
                want.position,
                [e.id for e in want.evidence],
            ), question
        assert svc.judge().current()._decoy_support is lent
        assert not (mem.path / OFFLINE_CALIBRATION).exists()  # every question used the Judge's
        assert emb.decoy_batches() == 2


def _text_search(query: str) -> tuple[Any, Any, int]:
    from ravenmem.runtime.service import tool_args
    from ravenmem.tools import get_tool

    tool = get_tool("text")
    return tool, tool.validate(tool_args("text", query, "query")), 5
