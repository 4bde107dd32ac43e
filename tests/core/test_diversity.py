"""Diverse results: no two text/image hits from the same moment and place unless asked."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import ravenmem
from ravenmem.memory import diversity
from ravenmem.tools import get_tool
from ravenmem.types import Frame, Hit, MemoryRecord, Pose
from tests.conftest import ColorEmbedder

T0 = 1_700_000_000.0


def rec(i: int, t: float, x: float = 0.0, yaw_deg: float = 0.0, quat: tuple | None = None) -> MemoryRecord:
    pose = Pose(x, 0.0, 0.0, math.radians(yaw_deg), quat)
    return MemoryRecord(id=i, t=T0 + t, pose=pose)


def test_same_view_needs_same_moment_place_and_heading() -> None:
    same = diversity.SameView(seconds=2.0, metres=0.5, degrees=30.0)
    a = rec(0, 0.0)
    assert same(a, rec(1, 1.9, x=0.4, yaw_deg=25))
    assert not same(a, rec(1, 2.1))  # another moment: the same place later may show something new
    assert not same(a, rec(1, 0.5, x=0.6))  # another place
    assert not same(a, rec(1, 0.5, yaw_deg=35))  # turned: a new view within the second
    assert not same(a, rec(1, 0.5, yaw_deg=-35))
    assert same(rec(0, 0.0, yaw_deg=179), rec(1, 0.1, yaw_deg=-179))  # 2 deg across the wrap
    tilt = (math.sin(math.radians(20)), 0.0, 0.0, math.cos(math.radians(20)))  # 40 deg roll, yaw 0
    flat = (0.0, 0.0, 0.0, 1.0)
    assert not same(rec(0, 0.0, quat=flat), rec(1, 0.1, quat=tilt))  # full 3-D angle with quaternions
    assert diversity.SameView() == diversity.SAME_VIEW  # the documented defaults: 2 s, 0.5 m, 30 deg


def test_pick_keeps_rank_order_and_drops_repeats_of_kept_hits() -> None:
    hits = [Hit(rec(i, t), score=1.0 - i / 10) for i, t in enumerate([0.0, 0.03, 10.0, 0.06, 20.0, 10.1])]
    assert [h.memory.id for h in diversity.pick(hits, 5)] == [0, 2, 4]
    assert [h.memory.id for h in diversity.pick(hits, 2)] == [0, 2]


def test_top_hits_asks_for_more_candidates_until_k_diverse() -> None:
    burst = [Hit(rec(i, i * 0.03)) for i in range(50)]  # 1.5 s of one view
    later = [Hit(rec(50 + i, 100.0 + 10 * i)) for i in range(3)]
    ranking = burst + later
    asked: list[int] = []

    def ranked(n: int) -> list[Hit]:
        asked.append(n)
        return ranking[:n]

    got = diversity.top_hits(ranked, 3, True, total=len(ranking))
    assert [h.memory.id for h in got] == [0, 50, 51]
    assert asked == [12, 48, 192]  # 4k, then 4x more while short and more may exist
    asked.clear()
    assert len(diversity.top_hits(ranked, 3, False, total=len(ranking))) == 3 and asked == [3]
    assert [h.memory.id for h in diversity.top_hits(lambda n: burst[:n], 3, True, total=50)] == [0]


@pytest.fixture
def burst_memory(tmp_path: Path):
    """Ten pure-red frames 0.1 s apart at one spot (the best match for "red"), and darker red
    frames at three other moments; green frames in between."""

    def img(rgb: tuple[int, int, int]) -> np.ndarray:
        a = np.zeros((24, 32, 3), np.uint8)
        a[:] = rgb
        return a

    frames = [Frame(img((255, 0, 0)), T0 + 0.1 * i, Pose(1.0, 2.0), index=i) for i in range(10)]
    for j, t in enumerate((30.0, 60.0, 90.0)):
        frames.append(Frame(img((220, 40, 40)), T0 + t, Pose(1.0, 2.0), index=10 + j))
        frames.append(Frame(img((0, 200, 0)), T0 + t + 5, Pose(3.0, 2.0), index=20 + j))
    m = ravenmem.create(tmp_path / "b.mem", embedder=ColorEmbedder(), ocr=False, thumb_size=0)
    m.add_frames(frames)
    yield m
    m.close()


def test_text_and_image_search_are_diverse_by_default(burst_memory) -> None:
    m = burst_memory
    div = m.search_text("red", k=4)
    assert [round(h.memory.t - T0) for h in div] == [0, 30, 60, 90]
    dense = m.search_text("red", k=4, diverse=False)
    assert [h.memory.frame_index for h in dense] == [0, 1, 2, 3]  # the burst; ties: earlier first
    assert m.search_texts(["red"], k=4, diverse=False)[0][0].memory.id == dense[0].memory.id
    like = m.search_image(memory_id=dense[0].memory.id, k=3)
    assert [round(h.memory.t - T0) for h in like] == [0, 30, 60]  # one view of its own moment, then others
    assert (
        len(
            {round(h.memory.t - T0) for h in m.search_image(memory_id=dense[0].memory.id, k=3, diverse=False)}
        )
        == 1
    )
    by_image = m.search_image(np.full((24, 32, 3), (255, 0, 0), np.uint8), k=2)
    assert [round(h.memory.t - T0) for h in by_image] == [0, 30]


def test_tools_table_passes_the_opt_out(burst_memory) -> None:
    text = get_tool("search_text")
    assert len({round(h.memory.t) for h in text.run(burst_memory, {"query": "red"}, 3)}) == 3
    assert (
        len({round(h.memory.t) for h in text.run(burst_memory, {"query": "red", "diverse": False}, 3)}) == 1
    )
