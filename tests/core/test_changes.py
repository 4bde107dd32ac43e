"""A world that changes: the rules of `ravenmem.memory.changes` on small hand-made timelines.

The robot stands at a few poses and looks around; a red picture is a view that shows the red
thing, a black one a view without it. Verdicts come from what the robot saw later from the
same pose: `still there`, `not revisited`, `moved` or `gone`.
"""

from __future__ import annotations

import math

import pytest

import ravenmem
from ravenmem.errors import InputError
from ravenmem.memory.places import ChangeHit
from ravenmem.memory.views import ChangeConfig, overlaps
from ravenmem.timeparse import fmt_time
from ravenmem.tools import TOOLS, hit_json
from ravenmem.types import Frame, MemoryRecord, Pose
from tests.conftest import solid

T0 = 1_700_000_000.0
DAY = 86_400.0
EAST, WEST, NORTH = 0.0, math.pi, math.pi / 2


def look(t: float, colour: str, x: float, y: float, yaw: float) -> Frame:
    return Frame(image=solid(colour), t=T0 + t, pose=Pose(x, y, 0.5, yaw), source="test", index=int(t * 10))


def first_pass() -> list[Frame]:
    """Day 1: the red thing in view from (0, 0) facing east for 3 s, then the robot turns away
    and drives on (west, then elsewhere): one place, seen once."""
    frames = [look(t, "red", 0.0, 0.0, EAST) for t in (0, 1, 2)]
    frames += [look(t, "black", 0.0, 0.0, WEST) for t in (3, 4)]
    frames += [look(5 + i, "black", 3.0 + i, 5.0, NORTH) for i in range(10)]
    return frames


def build(tmp_path, frames: list[Frame], name: str = "m.mem") -> ravenmem.Memory:
    from tests.conftest import ColorEmbedder

    mem = ravenmem.create(tmp_path / name, embedder=ColorEmbedder(), ocr=False, thumb_size=16)
    mem.add_frames(sorted(frames, key=lambda f: f.t))
    return mem


def ids_at(mem: ravenmem.Memory, *ts: float) -> list[int]:
    by_t = {round(r.t - T0, 3): r.id for r in mem.all_records()}
    return [by_t[t] for t in ts]


def test_a_thing_taken_away_is_gone_with_the_revisits_that_show_it(tmp_path) -> None:
    later = [look(DAY + t, "black", 0.0, 0.0, EAST) for t in (0, 1)] + [
        look(DAY + 2, "black", 0.0, 0.0, WEST)
    ]
    mem = build(tmp_path, first_pass() + later)
    w = mem.last_seen("red")
    assert [p.verdict for p in w.places] == ["gone"] and w.status == "gone" and w.now is None
    p = w.places[0]
    assert [h.memory.id for h in p.sightings] == ids_at(mem, 0, 1, 2)
    assert [h.memory.id for h in p.revisits] == ids_at(mem, DAY, DAY + 1) and p.revisited == T0 + DAY
    text = p.sentence()
    assert (
        f"looked at again at {fmt_time(T0 + DAY)}" in text and "without it" in text and text.endswith("gone")
    )
    assert w.latest is p and w.moved_from == []
    mem.close()


def test_a_thing_moved_elsewhere_is_now_there_and_its_old_place_says_moved(tmp_path) -> None:
    later = [look(DAY + t, "black", 0.0, 0.0, EAST) for t in (0, 1)]
    later += [look(DAY + 2, "black", 6.0, 0.0, WEST)] + [
        look(DAY + t, "red", 10.0, 0.0, NORTH) for t in (3, 4)
    ]
    mem = build(tmp_path, first_pass() + later)
    w = mem.last_seen("red")
    new, old = w.places
    assert (new.verdict, old.verdict, w.status) == ("not revisited", "moved", "not revisited")
    assert w.now is new and new.last.pose.x == 10.0 and new.last.t == T0 + DAY + 4
    assert old.moved_to == new.index == 1 and old.seen_since is not None
    assert old.seen_since.memory.t == T0 + DAY + 3 and w.moved_from == [old]
    first_since = f"(m{ids_at(mem, DAY + 3)[0]}), latest at place 1 (m{new.last.id} at"
    assert f"moved, seen elsewhere from {fmt_time(T0 + DAY + 3)} {first_since}" in old.sentence()
    assert old.newest_since is not None and old.newest_since.memory.id == new.last.id
    # as of the end of day 1, it was where the first pass saw it, and nothing had looked since
    before = mem.last_seen("red", before=T0 + 100)
    assert [p.verdict for p in before.places] == ["not revisited"] and before.now is not None
    assert before.now.last.t == T0 + 2
    mem.close()


def test_a_thing_seen_again_on_a_later_visit_is_still_there(tmp_path) -> None:
    later = [look(DAY + t, "red", 0.0, 0.0, EAST) for t in (0, 1)] + [look(DAY + 2, "black", 0.0, 0.0, WEST)]
    mem = build(tmp_path, first_pass() + later)
    w = mem.last_seen("red")
    assert [p.verdict for p in w.places] == ["still there"] and w.status == "still there"
    assert w.now is not None and w.now.last.t == T0 + DAY + 1 and w.now.later_visit
    assert len(w.now.sightings) == 5 and w.now.revisits == []
    mem.close()


def test_looking_away_and_back_on_the_same_pass_is_no_revisit(tmp_path) -> None:
    """Frames of the same pass that lose the thing are not evidence that it left: a revisit
    comes after the robot looked away *and* a pass later (30 x the keyframe spacing)."""
    frames = first_pass() + [look(16, "black", 0.0, 0.0, EAST)]
    mem = build(tmp_path, frames)
    w = mem.last_seen("red")
    assert [p.verdict for p in w.places] == ["not revisited"] and w.places[0].revisits == []
    # with a short pass, the same look back counts
    short = mem.last_seen("red", config=ChangeConfig(episode_gap_s=5.0))
    assert [p.verdict for p in short.places] == ["gone"] and short.places[0].revisited == T0 + 16
    mem.close()


def test_a_view_from_elsewhere_or_another_way_is_not_a_revisit(tmp_path) -> None:
    later = [
        look(DAY, "black", 0.0, 0.0, NORTH),
        look(DAY + 1, "black", 2.0, 0.0, EAST),
    ]  # turned 90 deg; 2 m away
    mem = build(tmp_path, first_pass() + later)
    assert [p.verdict for p in mem.last_seen("red").places] == ["not revisited"]
    wide = mem.last_seen("red", config=ChangeConfig(view_radius=2.5))
    assert [p.verdict for p in wide.places] == ["gone"]
    mem.close()


def test_views_overlap_by_position_and_full_orientation() -> None:
    def rec(x: float, pose: Pose) -> MemoryRecord:
        return MemoryRecord(id=0, t=0.0, pose=pose)

    a = rec(0, Pose(0, 0, 1, 0.0))
    assert overlaps(a, rec(0, Pose(1.0, 0.5, 1, math.radians(40))))
    assert not overlaps(a, rec(0, Pose(1.0, 0.5, 1, math.radians(50))))
    assert not overlaps(a, rec(0, Pose(1.6, 0.0, 1, 0.0)))
    # with quaternions, the whole rotation counts: same yaw but rolled 90 degrees is another view
    level = Pose.from_quaternion(0, 0, 1, 0, 0, 0, 1)
    rolled = Pose.from_quaternion(0, 0, 1, math.sin(math.pi / 4), 0, 0, math.cos(math.pi / 4))
    assert level.yaw == pytest.approx(rolled.yaw)
    assert overlaps(rec(0, level), rec(0, level)) and not overlaps(rec(0, level), rec(0, rolled))


def test_the_latest_mode_of_the_text_and_image_tools(tmp_path) -> None:
    later = [look(DAY + t, "black", 0.0, 0.0, EAST) for t in (0, 1)]
    later += [look(DAY + 2, "black", 6.0, 0.0, WEST)] + [
        look(DAY + t, "red", 10.0, 0.0, NORTH) for t in (3, 4)
    ]
    mem = build(tmp_path, first_pass() + later)
    best = TOOLS["search_text"].run(mem, {"query": "red"}, k=3)
    assert all(not isinstance(h, ChangeHit) and "change" not in hit_json(h, 1, T0) for h in best)
    hits = TOOLS["search_text"].run(mem, {"query": "red", "latest": True}, k=5)
    roles = [(h.change["place"], h.change["role"]) for h in hits if isinstance(h, ChangeHit)]
    assert roles == [(1, "sighting"), (2, "sighting"), (2, "revisit"), (2, "revisit")]
    assert [h.memory.t - T0 for h in hits] == [DAY + 4, 2, DAY, DAY + 1]
    row = hit_json(hits[1], 2, T0)
    assert row["change"]["verdict"] == "moved" and row["change"]["revisit_ids"] == ids_at(mem, DAY, DAY + 1)
    assert row["change"]["status"] == "not revisited" and "without it" in row["change"]["text"]
    assert len(TOOLS["search_text"].run(mem, {"query": "red", "latest": True}, k=1)) == 1  # k counts places
    assert (
        TOOLS["search_text"]
        .order_for(TOOLS["search_text"].validate({"query": "x", "latest": True}))
        .startswith("newest place first")
    )
    # the image tool: "where is the thing in memory m1 now?"
    like = TOOLS["search_image"].run(mem, {"memory_id": ids_at(mem, 1)[0], "latest": True}, k=5)
    assert [h.change["verdict"] for h in like if h.change["role"] == "sighting"] == ["not revisited", "moved"]
    attached = TOOLS["search_image"].run(mem, {"latest": True}, k=5, image=solid("red"))
    assert attached[0].memory.t == T0 + DAY + 4
    with pytest.raises(InputError, match="memory_id"):
        TOOLS["search_image"].run(mem, {"latest": True}, k=5)
    mem.close()


def test_nothing_that_stands_out_and_bad_input(tmp_path) -> None:
    mem = build(tmp_path, first_pass())
    w = mem.last_seen("green")  # nothing green: no memory stands out from the rest
    assert w.places == [] and w.status is None and w.now is None and "not seen" in w.summary()
    with pytest.raises(InputError, match="exactly one"):
        mem.last_seen()
    with pytest.raises(InputError, match="empty"):
        mem.last_seen("   ")
    with pytest.raises(InputError, match="no such memory"):
        mem.last_seen(memory_id=999)
    with pytest.raises(InputError, match="match_ratio"):
        ChangeConfig(match_ratio=1.5)
    with pytest.raises(InputError, match="latest"):
        TOOLS["search_text"].validate({"query": "red", "latest": "maybe"})
    mem.close()


class ProtocolOnly:
    """A memory that offers exactly `MemoryLike` (no store, no private parts): what a method may
    rely on. Any other attribute is an AttributeError, so probing for more would show."""

    def __init__(self, mem: ravenmem.Memory) -> None:
        self._mem = mem
        self.path = mem.path

    def __getattr__(self, name: str) -> object:
        from ravenmem.memory import MemoryLike

        if name.startswith("_") or name not in dir(MemoryLike):
            raise AttributeError(name)
        return getattr(self._mem, name)


def test_the_latest_mode_needs_only_the_memory_protocol(tmp_path) -> None:
    from ravenmem.agent.offline import OfflineReasoner
    from ravenmem.memory import MemoryLike

    later = [look(DAY + t, "black", 0.0, 0.0, EAST) for t in (0, 1)]
    later += [look(DAY + 2, "black", 6.0, 0.0, WEST)] + [
        look(DAY + t, "red", 10.0, 0.0, NORTH) for t in (3, 4)
    ]
    mem = build(tmp_path, first_pass() + later)
    like = ProtocolOnly(mem)
    assert isinstance(mem, MemoryLike) and isinstance(like, MemoryLike) and not hasattr(like, "store")
    hits = TOOLS["search_text"].run(like, {"query": "red", "latest": True}, k=5)
    assert hits == TOOLS["search_text"].run(mem, {"query": "red", "latest": True}, k=5)
    assert [h.memory.t - T0 for h in hits] == [DAY + 4, 2, DAY, DAY + 1]
    answers = [OfflineReasoner(m).ask("where is the red thing now?") for m in (mem, like)]
    assert answers[1].model_dump(exclude={"cost"}) == answers[0].model_dump(exclude={"cost"})
    assert not any("need a ravenmem Memory" in n for n in answers[1].notes)
    mem.close()
