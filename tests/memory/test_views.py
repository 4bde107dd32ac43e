"""The latest mode's view tests, fast forms against their definitions: `next_in_time` (no
memory in between) against the store's time order, `overlapping` against `overlaps`."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

import ravenmem
from ravenmem.errors import InputError
from ravenmem.memory import changes, views
from ravenmem.memory.places import Sightings
from ravenmem.memory.views import (
    ChangeConfig,
    _apart,
    group_sightings,
    next_in_time,
    overlap_rows,
    overlapping,
    overlaps,
)
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
        assert not next_in_time(mem, key(recs[2]), key(gone)) and not next_in_time(
            mem, key(gone), key(recs[4])
        )
        check_pairs(mem, [r for r in recs if r.id != gone.id])
    finally:
        mem.close()


def test_time_order_tells_which_sightings_are_apart(tmp_path) -> None:
    """`time_order` is each memory's place in (time, id) order on a chronological store (ties
    included; -1 for an id not stored; places close up after a forget), None on a store whose
    ids do not follow time. `_apart` (the latest mode's one call for all pairs of sightings in
    a row) never calls apart two memories that are next in time."""
    times = [0.0, 1.0, 1.0, 2.0, 5.0, 5.0, 5.0, 7.0, 9.0]
    mem = ravenmem.create(tmp_path / "m.mem", embedder=ColorEmbedder(), ocr=False, thumb_size=0)
    mem.add_frames([Frame(solid("red"), T0 + t, Pose(float(i), 0.0), "s", i) for i, t in enumerate(times)])
    try:
        recs = sorted(mem.all_records(), key=lambda r: (r.t, r.id))
        got = mem.store.time_order([r.id for r in recs] + [999])
        assert got is not None and got.tolist() == [*range(len(recs)), -1]
        for a, b in itertools.combinations(recs, 2):  # chronological pairs
            ids = [a.id, b.id]
            assert not (_apart(mem, ids)[0] and next_in_time(mem, key(a), key(b))), (a.id, b.id)
            assert _apart(mem, ids)[0] == (recs.index(b) != recs.index(a) + 1)
        mem.forget(ids=[recs[3].id])
        left = [r for r in recs if r.id != recs[3].id]
        assert mem.store.time_order([r.id for r in left]).tolist() == list(range(len(left)))
        assert mem.store.time_order([recs[3].id]).tolist() == [-1]
        assert _apart(mem, [recs[2].id, recs[4].id]).tolist() == [False]
        mem.add_frames([Frame(solid("red"), T0 + 3.0, Pose(0.0, 0.0), "s", 99)])  # back in time
        assert mem.store.time_order([recs[0].id]) is None
    finally:
        mem.close()


def key(r: MemoryRecord) -> tuple[float, int]:
    return (r.t, r.id)


def check_pairs(mem: ravenmem.Memory, recs: list) -> int:
    """Every ordered pair against the definition; how many are next to each other."""
    adjacent = 0
    for a, b in itertools.permutations(recs, 2):
        if (a.t, a.id) >= (b.t, b.id):
            continue
        step = mem.store.by_time(a.t, 2, Filter(before=b.t))
        want = [r.id for r in step] == [a.id, b.id]
        assert next_in_time(mem, key(a), key(b)) == want, (a.id, b.id)
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


class _RecordsOnly:
    """A store as a backend without the optional `CameraStore` methods shows it to the latest
    mode (e.g. Milvus): every call but `cameras`, `time_order` and `cameras_of` goes to the real store, so the
    latest mode reads records instead."""

    def __init__(self, store: object) -> None:
        self._store = store

    def __getattr__(self, name: str) -> object:
        if name in ("cameras", "time_order", "cameras_of"):
            raise AttributeError(name)
        return getattr(self._store, name)


def _loops(laps: int = 12) -> tuple[list[Frame], np.ndarray]:
    """A robot driving a 10 m square, 0.5 m a keyframe, a camera tilted by turns (quaternion
    poses on odd laps, yaw only on even ones); a red thing in view at the start of the first
    side for the first half, then at the third side; a green one in view for the first 8 laps
    only. Embeddings in ColorEmbedder's space: the colour of what is in view."""
    frames, emb = [], []
    per_lap = 80
    for i in range(laps * per_lap):
        lap, s = divmod(i, per_lap)
        edge, along = divmod(s * 0.5, 10.0)
        x, y, yaw = [
            (along, 0.0, 0.0),
            (10.0, along, math.pi / 2),
            (10 - along, 10.0, math.pi),
            (0.0, 10 - along, -math.pi / 2),
        ][int(edge)]
        pose = Pose(x, y, 1.0, yaw)
        if lap % 2:
            tilt = 0.2 * math.sin(i)
            pose = Pose.from_quaternion(x, y, 1.0, *_quat(yaw, tilt))
        red = (lap < laps // 2 and 2 <= s < 6) or (lap >= laps // 2 and 42 <= s < 46)
        green = lap < 8 and 22 <= s < 26
        v = np.array([1.0 if red else 0.1, 1.0 if green else 0.1, 0.1, 0.15 + 0.01 * (s % 5)], np.float32)
        frames.append(Frame(solid("black"), T0 + i, pose, "loop", i))
        emb.append(v / np.linalg.norm(v))
    return frames, np.array(emb, np.float32)


def _quat(yaw: float, pitch: float) -> tuple[float, float, float, float]:
    """The quaternion (x, y, z, w) of a yaw about z after a pitch about y."""
    cy, sy, cp, sp = math.cos(yaw / 2), math.sin(yaw / 2), math.cos(pitch / 2), math.sin(pitch / 2)
    return (-sy * sp, cy * sp, sy * cp, cy * cp)


def _decided(w: object) -> list[tuple[object, ...]]:
    return [
        (
            p.verdict,
            [h.memory.id for h in p.sightings],
            [(h.memory.id, round(h.score or 0.0, 6)) for h in p.revisits],
            p.revisit_count,
            p.later_visit,
        )
        for p in w.places  # type: ignore[attr-defined]
    ]


def test_the_latest_mode_decides_the_same_on_cameras_as_on_records(tmp_path) -> None:
    """The embedded store gives the latest mode cameras (poses from its in-RAM columns) where a
    backend without them gives records: the same places, sightings, revisits and verdicts, on a
    memory with quaternion and yaw-only poses, before and after a reopen (columns from their
    file), as of now and as of an earlier time."""
    frames, emb = _loops()
    mem = ravenmem.create(tmp_path / "m.mem", embedder=ColorEmbedder(), ocr=False, thumb_size=0)
    mem.add_frames(frames, embeddings=emb)
    mem.close()
    for _ in range(2):  # the first open loads the columns from SQLite, the second from their file
        mem = ravenmem.open(tmp_path / "m.mem", embedder=ColorEmbedder())
        try:
            real = mem.store
            for colour, before in (("red", None), ("green", None), ("red", T0 + 500)):
                mem.store = real
                on_cameras = mem.last_seen(colour, before=before)
                mem.store = _RecordsOnly(real)  # type: ignore[assignment]
                on_records = mem.last_seen(colour, before=before)
                assert _decided(on_cameras) == _decided(on_records)
                assert on_cameras.status == on_records.status
            mem.store = real
            red, green = mem.last_seen("red"), mem.last_seen("green")
            assert [p.verdict for p in red.places] == ["still there", "moved"]  # the setup holds
            assert green.status == "gone" and green.places[0].revisits
            recs = real.by_time(T0, 2000)
            cams = real.cameras(T0, 2000)  # type: ignore[attr-defined]
            assert cams.ids.tolist() == [r.id for r in recs] and np.array_equal(cams.t, [r.t for r in recs])
            want = np.array([[r.pose.x, r.pose.y, r.pose.yaw, *(r.pose.quat or (np.nan,) * 4)] for r in recs])
            assert np.allclose(cams.poses, want, atol=1e-6, equal_nan=True)
            assert np.isnan(cams.poses[:80, 3:]).all() and not np.isnan(cams.poses[80:160, 3:]).any()
        finally:
            mem.close()


def test_an_answer_reads_only_the_records_it_shows(tmp_path, monkeypatch) -> None:
    """`last_seen` decides on ids, times, cameras and scores; it reads the records of what its
    answer shows (each place's first, last and best sighting, the revisits) and a place's
    other sightings only when `Place.sightings` is asked for, while the memory is open."""
    frames, emb = _loops()
    mem = ravenmem.create(tmp_path / "m.mem", embedder=ColorEmbedder(), ocr=False, thumb_size=0)
    mem.add_frames(frames, embeddings=emb)
    read: list[int] = []
    get = mem.store.get
    monkeypatch.setattr(mem.store, "get", lambda ids, **kw: read.extend(ids) or get(ids, **kw))
    try:
        mem.last_seen("red")  # the whole-memory facts (a sample of records) are read once
        read.clear()
        w = mem.last_seen("red")
        sightings = {int(i) for p in w.places for i in p.found.ids}
        shown = {i for p in w.places for i in (p.first.id, p.last.id, p.best.memory.id)}
        shown |= {h.memory.id for p in w.places for h in (p.seen_since, p.newest_since) if h is not None}
        shown |= {h.memory.id for p in w.places for h in p.revisits}
        assert set(read) <= shown and len(sightings & set(read)) < len(sightings) // 4
        read.clear()
        for p in w.places:  # the rest when asked for: the same sightings, chronological
            got = p.sightings
            assert [h.memory.id for h in got] == p.found.ids.tolist()
            assert [h.score for h in got] == p.found.scores.tolist()
            assert [(h.memory.t, h.memory.id) for h in got] == sorted((h.memory.t, h.memory.id) for h in got)
            assert got[-1].memory == p.last and p.seen == len(got)
        assert set(read) == sightings - shown  # each record read once
        later = mem.last_seen("green")
    finally:
        mem.close()
    with pytest.raises(InputError, match="ask before closing"):
        _ = later.places[0].sightings


def test_revisits_of_a_place_whose_sightings_are_all_in_hand_are_not_scored(tmp_path, monkeypatch) -> None:
    """When a place's last search for later sightings found all of them (`grow` says so), none
    of its later views shows the thing: its revisits are decided without scoring those views,
    and they are the ones scoring every view finds, with a small pool too (searches that stop
    at their best `pool` and say they are not complete)."""
    frames, emb = _loops()
    mem = ravenmem.create(tmp_path / "m.mem", embedder=ColorEmbedder(), ocr=False, thumb_size=0)
    mem.add_frames(frames, embeddings=emb)
    scored: list[int] = []
    score = views._scores
    monkeypatch.setattr(views, "_scores", lambda m, q, found: scored.append(len(found)) or score(m, q, found))
    grow = changes.grow
    try:
        for colour, cfg in itertools.product(("red", "green"), (None, ChangeConfig(pool=3))):
            monkeypatch.setattr(changes, "grow", grow)
            scored.clear()
            quick = mem.last_seen(colour, config=cfg)
            skipped = not scored
            monkeypatch.setattr(changes, "grow", lambda *a: grow(*a) and False)  # never sure
            scored.clear()
            every = mem.last_seen(colour, config=cfg)
            assert scored and _decided(quick) == _decided(every) and quick.status == every.status
            assert any(p.revisits for p in every.places)
            if cfg is None:
                assert skipped  # each place's later sightings were all in hand
    finally:
        mem.close()


def _groups_one_by_one(mem: object, seen: Sightings, s: ChangeConfig) -> list[list[int]]:
    """The grouping rule as first written: each sighting, best first, joins the first seed it
    overlaps (`overlaps`' arithmetic) or becomes one; then neighbours in time with no memory
    between them join."""
    n, rows = len(seen), seen.poses.tolist()
    parent = list(range(n))

    def root(i: int) -> int:
        while parent[i] != i:
            i = parent[i]
        return i

    seeds: list[int] = []
    for i in sorted(range(n), key=lambda i: -seen.scores[i]):
        home = next((j for j in seeds if overlap_rows(rows[i], rows[j], s)), None)
        if home is None:
            seeds.append(i)
        else:
            parent[root(i)] = root(home)
    for i in range(n - 1):
        if root(i) != root(i + 1) and next_in_time(mem, seen.key(i), seen.key(i + 1)):  # type: ignore[arg-type]
            parent[root(i)] = root(i + 1)
    groups: dict[int, list[int]] = {}
    for i in range(n):
        groups.setdefault(root(i), []).append(i)
    return list(groups.values())


def test_grouping_into_places_is_the_one_by_one_rule(tmp_path) -> None:
    """`group_sightings` (seeds claiming every overlapping sighting at once) makes the places
    the one-by-one rule makes, on sightings drawn from a memory with quaternion and yaw-only
    poses, runs of neighbours in time and tied scores."""
    frames, emb = _loops()
    mem = ravenmem.create(tmp_path / "m.mem", embedder=ColorEmbedder(), ocr=False, thumb_size=0)
    mem.add_frames(frames, embeddings=emb)
    rng, several, joined = np.random.default_rng(3), 0, 0
    try:
        cams = mem.store.cameras(T0, 2000)  # type: ignore[attr-defined]
        for trial in range(30):
            rows = np.sort(rng.choice(len(cams), int(rng.integers(2, 120)), replace=False))
            if trial % 3 == 0:  # runs of neighbours in time
                start = int(rng.integers(0, len(cams) - 40))
                rows = np.unique(np.concatenate([rows, np.arange(start, start + 30)]))
            scores = rng.choice([0.5, 0.6, 0.7], len(rows)) if trial % 2 else rng.random(len(rows))
            seen = Sightings.of(cams.take(rows), scores)
            s = ChangeConfig(view_radius=float(rng.choice([0.6, 1.5, 4.0])))
            got = [g.tolist() for g in group_sightings(mem, seen, s)]
            assert got == _groups_one_by_one(mem, seen, s)
            several += len(got) > 1
            joined += any(len(g) > 1 for g in got)
        assert several > 20 and joined > 20  # neither one place nor one per sighting
    finally:
        mem.close()


def test_the_first_camera_looking_away_is_found_the_same_from_a_few_views_first() -> None:
    """`_first_away` (tests the sightings taken about then first, then the rest of them only
    for the cameras those miss) finds the camera that every sighting's overlap test finds."""
    rng = np.random.default_rng(9)
    s = ChangeConfig()
    for _ in range(200):
        n, m = int(rng.integers(1, 20)), int(rng.integers(1, 60))
        cams = np.column_stack([rng.uniform(0, 6, (n, 2)), rng.uniform(-3, 3, n), np.full((n, 4), np.nan)])
        seen = np.column_stack([rng.uniform(0, 6, (m, 2)), rng.uniform(-3, 3, m), np.full((m, 4), np.nan)])
        near = seen[: int(rng.integers(0, m + 1))]
        away = np.flatnonzero(~views.overlapping_poses(cams, seen, s))
        assert views._first_away(cams, seen, near, s) == (int(away[0]) if len(away) else None)
