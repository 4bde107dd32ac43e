"""The latest mode's view tests, fast forms against their definitions: `next_in_time` (no
memory in between) against the store's time order, `overlapping` against `overlaps`."""

from __future__ import annotations

import itertools
import math

import numpy as np

import ravenmem
from ravenmem.memory.views import ChangeConfig, next_in_time, overlapping, overlaps
from ravenmem.types import Filter, Frame, MemoryRecord, Pose
from tests.conftest import ColorEmbedder, solid

T0 = 1_700_000_000.0


def test_next_in_time_is_the_next_in_time_then_id_order(tmp_path) -> None:
    """Memories with shared timestamps and ids out of time order: for every ordered pair, b is
    next after a exactly when the first two memories of [a.t, b.t] in (time, id) order are a, b
    (what the latest mode asked the store before); a forgotten one is next to nothing."""
    times = [0.0, 1.0, 1.0, 2.0, 5.0, 5.0, 5.0, 3.0, 9.0]  # ids 1..9: id 8 (t=3) added late
    mem = ravenmem.create(tmp_path / "m.mem", embedder=ColorEmbedder(), ocr=False, thumb_size=0)
    frames = [Frame(solid("red"), T0 + t, Pose(float(i), 0.0), "s", i) for i, t in enumerate(times)]
    mem.add_frames(frames)
    try:
        recs = sorted(mem.all_records(), key=lambda r: (r.t, r.id))
        assert len({r.t for r in recs}) < len(recs)  # ties are there
        assert 0 < check_pairs(mem, recs) < len(recs)  # both answers were checked
        gone = recs[3]
        mem.forget(ids=[gone.id])
        assert not next_in_time(mem, recs[2], gone) and not next_in_time(mem, gone, recs[4])
        check_pairs(mem, [r for r in recs if r.id != gone.id])
    finally:
        mem.close()


def check_pairs(mem: ravenmem.Memory, recs: list) -> int:
    """Every ordered pair against the definition; how many are next to each other."""
    adjacent = 0
    for a, b in itertools.permutations(recs, 2):
        if (a.t, a.id) >= (b.t, b.id):
            continue
        step = mem.store.by_time(a.t, 2, Filter(before=b.t))
        want = [r.id for r in step] == [a.id, b.id]
        assert next_in_time(mem, a, b) == want, (a.id, b.id)
        adjacent += want
    return adjacent


def test_overlapping_is_overlaps_over_all_pairs() -> None:
    """The vectorised test gives `overlaps`'s answer for every record against a set of cameras:
    yaw-only poses, quaternion poses, a mix, headings across +-pi, distances at the radius."""
    rng = np.random.default_rng(0)

    def rec(i: int) -> MemoryRecord:
        x, y = rng.uniform(-3, 3, 2)
        yaw = float(rng.uniform(-math.pi, math.pi))
        quat = None
        if i % 3 == 0:
            tilt = float(rng.uniform(-0.4, 0.4))
            quat = (0.0, math.sin(tilt / 2), 0.0, math.cos(tilt / 2))
            quat = tuple(float(v) for v in quat)  # type: ignore[assignment]
        return MemoryRecord(id=i, t=T0 + i, pose=Pose(float(x), float(y), 0.0, yaw, quat))

    recs = [rec(i) for i in range(300)]
    edge = recs[0].pose
    recs.append(MemoryRecord(id=999, t=T0, pose=Pose(edge.x + 1.5, edge.y, 0.0, edge.yaw)))  # at the radius
    for s in (ChangeConfig(), ChangeConfig(view_radius=0.7, view_angle_deg=20.0)):
        for cams in (recs[:1], recs[:17], recs[100:160]):
            want = [any(overlaps(r, c, s) for c in cams) for r in recs]
            assert overlapping(recs, cams, s).tolist() == want
            assert 0 < sum(want) < len(recs)
    assert overlapping([], recs, ChangeConfig()).tolist() == []
    assert overlapping(recs[:3], [], ChangeConfig()).tolist() == [False] * 3
