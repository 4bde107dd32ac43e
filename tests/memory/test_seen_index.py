"""The latest mode's whole-memory facts (`seen_index`) are read once per memory state: the same
object answers until a write changes the memory."""

from __future__ import annotations

import ravenmem
from ravenmem.memory.seen_index import seen_index
from ravenmem.types import Frame, Pose
from tests.conftest import ColorEmbedder, solid

T0 = 1_700_000_000.0


def frames(start: int, n: int) -> list[Frame]:
    colors = ("red", "green", "blue")
    return [Frame(solid(colors[i % 3]), T0 + i, Pose(float(i), 0.0), "s", i) for i in range(start, start + n)]


def test_the_facts_are_kept_until_a_write(tmp_path) -> None:
    path = tmp_path / "m.mem"
    mem = ravenmem.create(path, embedder=ColorEmbedder(), ocr=False, thumb_size=0)
    mem.add_frames(frames(0, 30))
    try:
        first = seen_index(mem)
        assert seen_index(mem) is first and len(first.sample) == 30 and first.spacing == 1.0
        mem.add_frames(frames(30, 10))
        added = seen_index(mem)
        assert added is not first and len(added.sample) == 40
        gone = mem.store.select()[:10]
        mem.forget(ids=[int(i) for i in gone])
        forgot = seen_index(mem)
        assert forgot is not added and len(forgot.sample) == 30
        assert seen_index(mem) is forgot
        mem.add_frames(frames(40, 5))  # as many added as forgotten: the count alone would not tell
        mem.forget(ids=[int(i) for i in mem.store.select()[:5]])
        assert mem.count() == 30 and seen_index(mem) is not forgot
    finally:
        mem.close()
