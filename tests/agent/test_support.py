"""ravenmem.agent.support: search hits judged by the rule the offline reasoner declines by."""

from __future__ import annotations

from pathlib import Path

import ravenmem
from ravenmem.agent.offline import OfflineReasoner
from ravenmem.agent.support import Judge, judged
from tests.agent.conftest import scene_frames
from tests.conftest import ColorEmbedder


def test_hits_are_supported_exactly_when_ask_finds_the_thing(tmp_path: Path) -> None:
    with ravenmem.create(tmp_path / "m.mem", embedder=ColorEmbedder(), ocr=False) as mem:
        mem.add_frames(scene_frames())
        for query in ("red", "magenta", "a smell of toast", "an elephant"):
            hits = judged(mem, query, mem.search_text(query, k=3))
            found = OfflineReasoner(mem).ask(f"where did I see {query}?").found
            assert any(h.supported for h in hits) == found, query
            assert all(h.supported is not None for h in hits)
        support, thr = OfflineReasoner(mem).support("red")
        assert [h.supported for h in judged(mem, "red", mem.search_text("red", k=12))] == [
            support.get(h.memory.id, float("-inf")) > thr for h in mem.search_text("red", k=12)
        ]


def test_a_judge_calibrates_again_when_a_live_memory_doubles(tmp_path: Path) -> None:
    frames = scene_frames()
    with ravenmem.create(tmp_path / "m.mem", embedder=ColorEmbedder(), ocr=False) as mem:
        mem.add_frames(frames[:4])
        judge = Judge(mem)
        first = judge.reasoner
        judge.mark("red", mem.search_text("red", k=2))
        mem.add_frames(frames[4:8])  # 8: twice as many, the same calibration still holds
        judge.mark("red", mem.search_text("red", k=2))
        assert judge.reasoner is first
        mem.add_frames(frames[8:])  # 12: past twice the 4 it was calibrated on
        judge.mark("red", mem.search_text("red", k=2))
        assert judge.reasoner is not first
