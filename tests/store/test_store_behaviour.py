"""Behaviour every store backend must share, checked against numpy brute force."""

from __future__ import annotations

from collections.abc import Iterator

import numpy as np
import pytest

from ravenmem.errors import EmbedderMismatchError, InputError
from ravenmem.store import Store
from ravenmem.types import Filter, MemoryRecord, Pose, Region
from tests.store.store_helpers import BACKENDS, StoreOpener, make_records, opener, robot_stream

N, DIM = 400, 16
Data = tuple[Store, list[MemoryRecord], np.ndarray]


@pytest.fixture(scope="module", params=BACKENDS)
def filled(request: pytest.FixtureRequest, tmp_path_factory: pytest.TempPathFactory) -> Iterator[Data]:
    """A store with N memories inserted out of chronological order, in two batches."""
    store = opener(request.param, tmp_path_factory.mktemp("filled"), request)(dim=DIM)
    recs = make_records(N, shuffle=True)
    raw = robot_stream(N, DIM, seed=1, jump_every=40) * np.random.default_rng(2).uniform(0.5, 3, (N, 1))
    ids = store.add(recs[:150], raw[:150]) + store.add(recs[150:], raw[150:].astype(np.float64))
    assert ids == sorted(ids) and len(set(ids)) == N, "ids must be unique and increasing"
    recs = [r.with_id(i) for r, i in zip(recs, ids, strict=True)]
    unit = raw / np.linalg.norm(raw, axis=1, keepdims=True)
    yield store, recs, unit.astype(np.float32)
    store.close()


def brute_vector(recs: list[MemoryRecord], emb: np.ndarray, q: np.ndarray, k: int, filt: Filter | None):
    ok = np.array([filt is None or filt.accepts(r) for r in recs])
    scores = emb @ (q / np.linalg.norm(q))
    order = sorted(np.flatnonzero(ok), key=lambda i: (-scores[i], recs[i].id))[:k]
    return [recs[i].id for i in order], [float(scores[i]) for i in order]


FILTERS = [
    Filter(after=1_700_000_000.0 + 40, before=1_700_000_000.0 + 90),
    Filter(region=Region(10.0, 0.0, 3.0)),
    Filter(after=1_700_000_000.0 + 100, region=Region(-10.0, 0.0, 5.0)),
    Filter(before=1_700_000_000.0 + 12.0),
    Filter(after=1_800_000_000.0),  # accepts nothing
]


def test_get_round_trip(filled: Data) -> None:
    store, recs, emb = filled
    pick = [recs[7].id, recs[3].id, recs[7].id, recs[250].id]
    got = store.get(pick, with_embeddings=True)
    assert [g.id for g in got] == pick
    for g, i in zip(got, [7, 3, 7, 250], strict=True):
        want = recs[i]
        assert (g.t, g.pose, g.source, g.frame_index, g.image_path, g.ocr_text) == (
            want.t,
            want.pose,
            want.source,
            want.frame_index,
            want.image_path,
            want.ocr_text,
        )
        assert g.embedding is not None and np.allclose(g.embedding, emb[i], atol=1e-6)
    assert store.get([recs[1].id])[0].embedding is None
    assert store.count() == N
    with pytest.raises(KeyError):
        store.get([recs[0].id, 10**9])


def test_vector_scores_match_numpy(filled: Data) -> None:
    store, recs, emb = filled
    rng = np.random.default_rng(5)
    for qi in rng.choice(N, 5, replace=False):
        q = emb[qi] + 0.05 * rng.normal(size=DIM)
        hits = store.search_vector(q.astype(np.float32), 8)
        ids, scores = brute_vector(recs, emb, q, 8, None)
        assert [h[0] for h in hits] == ids
        assert np.allclose([h[1] for h in hits], scores, atol=1e-5)
    assert store.search_vector(emb[0], 0) == []


@pytest.mark.parametrize("fi", range(len(FILTERS)))
def test_vector_filters_exact(filled: Data, fi: int) -> None:
    store, recs, emb = filled
    filt = FILTERS[fi]
    q = emb[123] + 0.1 * np.random.default_rng(fi).normal(size=DIM)
    hits = store.search_vector(q.astype(np.float32), 6, filt)
    ids, scores = brute_vector(recs, emb, q, 6, filt)
    assert [h[0] for h in hits] == ids
    assert np.allclose([h[1] for h in hits], scores, atol=1e-5)
    assert all(filt.accepts(r) for r in store.get([h[0] for h in hits]))


@pytest.mark.parametrize("fi", [None, *range(len(FILTERS))])
def test_a_score_floor_keeps_the_best_that_reach_it(filled: Data, fi: int | None) -> None:
    """`min_score`: the top k of what scores at least the floor, exact or not; fewer when
    fewer reach it; a floor that is no number is refused."""
    store, recs, emb = filled
    filt = None if fi is None else FILTERS[fi]
    q = (emb[57] + 0.1 * np.random.default_rng(3).normal(size=DIM)).astype(np.float32)
    ids, scores = brute_vector(recs, emb, q, N, filt)
    for k, rank in ((10, 3), (10, 25), (4, 0)):
        floor = scores[rank] if rank < len(scores) else 0.0
        want = [(i, sc) for i, sc in zip(ids, scores, strict=True) if sc >= floor - 1e-6][:k]
        for exact in (False, True):
            got = store.search_vector(q, k, filt, exact=exact, min_score=floor - 1e-6)
            assert [h[0] for h in got] == [w[0] for w in want]
            assert np.allclose([h[1] for h in got], [w[1] for w in want], atol=1e-5)
    assert store.search_vector(q, 5, filt, min_score=1.01) == []
    for bad in (float("nan"), "0.5", True):
        with pytest.raises(InputError, match="min_score"):
            store.search_vector(q, 5, filt, min_score=bad)  # type: ignore[arg-type]


def test_candidates_sets_how_many_are_scored_exactly(filled: Data) -> None:
    """`candidates`: the store's best k, each with its exact score, best first (the exact top
    k where the index is exact, as here); a count that is no whole number >= 1 is refused."""
    store, recs, emb = filled
    q = (emb[200] + 0.1 * np.random.default_rng(4).normal(size=DIM)).astype(np.float32)
    for filt in (None, FILTERS[1]):
        ids, scores = brute_vector(recs, emb, q, 7, filt)
        for candidates in (7, 30):
            got = store.search_vector(q, 7, filt, candidates=candidates)
            assert [h[0] for h in got] == ids
            assert np.allclose([h[1] for h in got], scores, atol=1e-5)
    for bad in (0, -3, 2.5, "7", True):
        with pytest.raises(InputError, match="candidates"):
            store.search_vector(q, 5, candidates=bad)  # type: ignore[arg-type]


def test_by_time_starts_at_t_in_order(filled: Data) -> None:
    store, recs, _ = filled
    chrono = sorted(recs, key=lambda r: (r.t, r.id))
    start = chrono[100]
    got = store.by_time(start.t, 5)
    assert [g.id for g in got] == [r.id for r in chrono[100:105]]  # starts at t, not centred on it
    got = store.by_time(start.t + 0.25, 3)
    assert [g.id for g in got] == [r.id for r in chrono[101:104]]
    assert [g.id for g in store.by_time(chrono[-2].t, 10)] == [r.id for r in chrono[-2:]]
    assert store.by_time(chrono[-1].t + 1, 5) == []
    filt = Filter(region=Region(-10.0, 0.0, 4.0), before=chrono[300].t)
    want = [r.id for r in chrono if r.t >= start.t and filt.accepts(r)][:4]
    assert [g.id for g in store.by_time(start.t, 4, filt)] == want


@pytest.mark.parametrize(
    "x,y,z,radius,filt",
    [
        (3.0, 5.0, None, None, None),
        (3.0, 5.0, 1.5, None, None),
        (-9.0, 1.0, None, 1.2, None),
        (0.0, 0.0, None, 0.5, None),  # the loop's centre: nothing within 0.5 m
        (9.5, 0.5, 0.2, None, Filter(after=1_700_000_000.0 + 100)),
    ],
)
def test_nearest_matches_brute_force(filled: Data, x, y, z, radius, filt) -> None:
    store, recs, _ = filled
    k = 7
    d = [
        float(
            np.sqrt((r.pose.x - x) ** 2 + (r.pose.y - y) ** 2 + (0.0 if z is None else (r.pose.z - z) ** 2))
        )
        for r in recs
    ]
    cand = [(recs[i].id, d[i]) for i in range(N) if (radius is None or d[i] <= radius)]
    cand = [c for c in cand if filt is None or filt.accepts(recs[[r.id for r in recs].index(c[0])])]
    want = sorted(cand, key=lambda c: (c[1], c[0]))[:k]
    got = store.nearest(x, y, z, k, radius=radius, filt=filt)
    assert [g[0] for g in got] == [w[0] for w in want]
    assert np.allclose([g[1] for g in got], [w[1] for w in want])


def test_search_text(filled: Data) -> None:
    store, recs, _ = filled
    hits = store.search_text("fire exit", 50)
    assert hits and all(0.0 < s <= 1.0 for _, s in hits)
    assert [s for _, s in hits] == sorted((s for _, s in hits), reverse=True)
    texts = {r.id: r.ocr_text for r in recs}
    full = [i for i, s in hits if s == pytest.approx(1.0)]
    assert full and all(texts[i] == "Fire Exit ->" for i in full)
    assert all("exit" in texts[i].lower() for i, _ in hits)
    n_exit = sum("exit" in t.lower() for t in texts.values())
    assert len(store.search_text("EXIT", 1000)) == n_exit
    cafe = store.search_text("CAFE OLE", 3)  # OCR often drops accents: folded away on both sides
    assert len(cafe) == 3 and all(texts[i] == "Café Olé" and s == pytest.approx(1.0) for i, s in cafe)
    assert all("ro" in texts[i].lower() for i, _ in store.search_text("ro", 5))  # shorter than a trigram
    assert store.search_text("", 5) == [] and store.search_text("  !? ", 5) == []
    assert store.search_text("zebra", 5) == []
    filt = Filter(after=recs[0].t)
    assert all(filt.accepts(r) for r in store.get([i for i, _ in store.search_text("exit", 20, filt)]))


def test_stats(filled: Data) -> None:
    store, recs, _ = filled
    st = store.stats()
    assert st["count"] == N
    assert st["t_min"] == min(r.t for r in recs) and st["t_max"] == max(r.t for r in recs)
    assert st["x_min"] == pytest.approx(min(r.pose.x for r in recs))
    assert st["y_max"] == pytest.approx(max(r.pose.y for r in recs))


def test_reopen_meta_ids_and_dim_check(open_fn: StoreOpener) -> None:
    store = open_fn(dim=DIM)
    assert isinstance(store, Store)  # the runtime-checkable protocol
    recs = make_records(30)
    emb = robot_stream(30, DIM, seed=3)
    first = store.add(recs[:20], emb[:20])
    store.set_meta("embedder", "test-embedder")
    store.close()
    store = open_fn(dim=DIM)
    try:
        assert store.count() == 20 and store.get_meta("embedder") == "test-embedder"
        assert store.get_meta("missing") is None
        assert store.search_vector(emb[5], 1)[0][0] == first[5]
        more = store.add(recs[20:], emb[20:])
        assert min(more) > max(first)
        assert store.search_vector(emb[25], 1)[0][0] == more[5]
    finally:
        store.close()
    with pytest.raises(EmbedderMismatchError):
        open_fn(dim=DIM * 2)


def test_empty_store_and_bad_input(open_fn: StoreOpener) -> None:
    store = open_fn(dim=8)
    try:
        q = np.ones(8, np.float32)
        assert store.search_vector(q, 5) == [] and store.search_text("exit", 5) == []
        assert store.by_time(0.0, 5) == [] and store.nearest(0.0, 0.0, None, 5) == []
        assert store.add([], np.zeros((0, 8), np.float32)) == []
        recs = make_records(3)
        with pytest.raises(InputError, match="shape"):
            store.add(recs, np.ones((3, 4), np.float32))
        with pytest.raises(InputError, match="rows"):
            store.add(recs, np.ones((2, 8), np.float32))
        bad = np.ones((3, 8), np.float32)
        bad[1, 2] = np.nan
        with pytest.raises(InputError, match="NaN"):
            store.add(recs, bad)
        with pytest.raises(InputError, match="zero"):
            store.add(recs, np.zeros((3, 8), np.float32))
        with pytest.raises(InputError, match="query"):
            store.search_vector(np.ones(5), 3)
        with pytest.raises(InputError, match="k"):
            store.search_vector(q, -1)
        with pytest.raises(InputError, match="radius"):
            store.nearest(0.0, 0.0, None, 3, radius=-1.0)
        assert store.count() == 0
    finally:
        store.close()


def test_source_frames(filled: Data) -> None:
    """Every memory of one source, sorted by (frame_index, id), with exact timestamps."""
    store, recs, _ = filled
    for source in ("cam0", "cam1"):
        got = store.source_frames(source)
        want = sorted((r.frame_index, r.id, r.t) for r in recs if r.source == source)
        assert list(zip(got.frame_index.tolist(), got.ids.tolist(), got.t.tolist())) == want
        assert got.t.dtype == np.float64 and got.ids.dtype == np.int64
    assert len(store.source_frames("cam")) == 0 and len(store.source_frames("")) == 0  # exact match only
    with pytest.raises(InputError, match="source"):
        store.source_frames(None)  # type: ignore[arg-type]


def test_source_frames_odd_names_and_repeats(open_fn: StoreOpener) -> None:
    """Source strings are data, never syntax: quotes, backslashes, accents, emoji; a frame stored
    twice (as appends did before ingest became idempotent) is listed twice."""
    names = ['tum:a"b', "video:c\\d.mp4", "folder:é ü/😀", "o'k", "tab\tx"]
    store = open_fn(dim=DIM)
    try:
        recs = make_records(3 * len(names))
        for i, r in enumerate(recs):
            r.source, r.frame_index = names[i % len(names)], 10 - i // len(names)
        ids = store.add(recs, robot_stream(len(recs), DIM, seed=4))
        again = store.add([recs[0]], robot_stream(1, DIM, seed=5))  # frame 10 of names[0], once more
        for j, name in enumerate(names):
            got = store.source_frames(name)
            mine = [(recs[i].frame_index, ids[i]) for i in range(j, len(recs), len(names))]
            if j == 0:
                mine.append((10, again[0]))
            assert list(zip(got.frame_index.tolist(), got.ids.tolist())) == sorted(mine)
        assert store.source_frames(names[0]).frame_index.tolist() == [8, 9, 10, 10]
    finally:
        store.close()


def test_select_and_delete_match_numpy(open_fn: StoreOpener) -> None:
    """`select` is the filter's exact id set; `delete` forgets memories from every tool, the
    count and reopening, returns how many existed, and never lets an id come back."""
    store = open_fn(dim=DIM)
    recs = make_records(N, seed=4, shuffle=True)
    emb = robot_stream(N, DIM, seed=5, jump_every=40)
    ids = store.add(recs[:200], emb[:200]) + store.add(recs[200:], emb[200:])
    recs = [r.with_id(i) for r, i in zip(recs, ids, strict=True)]
    try:
        assert store.select().tolist() == ids
        for filt in FILTERS:
            assert store.select(filt).tolist() == [r.id for r in recs if filt.accepts(r)]
            assert store.count(filt) == sum(filt.accepts(r) for r in recs)
        t_cut = sorted(r.t for r in recs)[N // 4]
        forget = store.select(Filter(before=t_cut)).tolist() + [ids[-1], ids[5], ids[5], 10**9]
        gone = set(forget) - {10**9}
        assert store.delete(np.array(forget)) == len(gone)
        assert store.delete(sorted(gone)) == 0 and store.delete([]) == 0
        assert store.count() == N - len(gone)
        with pytest.raises(KeyError):
            store.get([ids[5]])
        with pytest.raises(InputError, match="ids"):
            store.delete(["seven"])  # type: ignore[list-item]
        keep = [i for i, r in enumerate(recs) if r.id not in gone]
        left, left_emb = [recs[i] for i in keep], emb[keep]
        assert store.select().tolist() == [r.id for r in left]
        for filt in FILTERS:  # the count of a filter forgets what was forgotten too
            assert store.count(filt) == sum(filt.accepts(r) for r in left)
        rng = np.random.default_rng(6)
        for filt in [None, *FILTERS[:3]]:
            for qi in rng.choice(N, 3, replace=False):
                q = emb[qi] + 0.05 * rng.normal(size=DIM)
                hits = store.search_vector(q.astype(np.float32), 8, filt)
                assert [h[0] for h in hits] == brute_vector(left, left_emb, q, 8, filt)[0]
        assert not gone & {i for i, _ in store.search_text("exit", 1000)}
        chrono = sorted(left, key=lambda r: (r.t, r.id))
        assert [g.id for g in store.by_time(0.0, 5)] == [r.id for r in chrono[:5]]
        near = store.nearest(10.0, 0.0, None, 20)
        d = {r.id: float(np.hypot(r.pose.x - 10.0, r.pose.y)) for r in left}
        assert [i for i, _ in near] == sorted(d, key=lambda i: (d[i], i))[:20]
        store.close()
        store = open_fn(dim=DIM)
        assert store.count() == N - len(gone) and store.select().tolist() == [r.id for r in left]
        assert store.search_vector(emb[5], 1)[0][0] != ids[5]
        new = store.add(make_records(2, seed=9), robot_stream(2, DIM, seed=9))
        assert min(new) > ids[-1], "the deleted newest id must not be reused"
    finally:
        store.close()


def test_add_many_imports_and_resumes(open_fn: StoreOpener) -> None:
    store = open_fn(dim=DIM)
    recs = make_records(N, seed=7)
    emb = robot_stream(N, DIM, seed=8, jump_every=50)
    batches = [(recs[s : s + 90], emb[s : s + 90]) for s in range(0, N, 90)]
    try:
        assert store.add_many(iter(batches[:2]), resume="run1") == 180
        assert store.add_many(iter(batches), resume="run1") == N - 180  # continues after 180 rows
        assert store.add_many(iter(batches), resume="run1") == 0
        assert store.count() == N
        got = store.get(list(range(1, N + 1)), with_embeddings=True)
        assert [g.t for g in got] == [r.t for r in recs] and [g.ocr_text for g in got] == [
            r.ocr_text for r in recs
        ]
        assert all(
            g.embedding is not None and np.allclose(g.embedding, e, atol=1e-6) for g, e in zip(got, emb)
        )
        for qi in (0, 211, N - 1):
            assert store.search_vector(emb[qi], 1)[0][0] == qi + 1
        with pytest.raises(InputError, match="shape"):
            store.add_many([(recs[:2], np.ones((2, DIM + 1), np.float32))])
        assert store.add_many([(recs[:3], emb[:3])]) == 3 and store.count() == N + 3
    finally:
        store.close()


def test_set_poses_moves_memories_for_every_tool_and_reopen(open_fn: StoreOpener) -> None:
    """`set_poses` (re-anchoring into another map) changes where memories are for the position
    tool, the filters, `get` and `stats`, after a reopen too; the vectors, times and texts stay;
    an unknown id changes nothing."""
    store = open_fn(dim=DIM)
    recs = make_records(120, seed=11)
    emb = robot_stream(120, DIM, seed=12)
    ids = store.add(recs, emb)
    recs = [r.with_id(i) for r, i in zip(recs, ids, strict=True)]
    try:
        store.select(Filter(region=Region(0.0, 0.0, 1.0)))  # the columns are loaded (and cached)
        c, s = np.cos(0.5), np.sin(0.5)

        def moved(p: Pose) -> Pose:  # a yaw of 0.5 rad about z, then 100 m along x
            q = p.quat and (0.0, 0.0, *_turn(p.quat[2:], 0.25))
            return Pose(c * p.x - s * p.y + 100.0, s * p.x + c * p.y, p.z, p.yaw + 0.5, q)

        new = [moved(r.pose) for r in recs]
        with pytest.raises(KeyError):
            store.set_poses([ids[0], 10**9], [new[0], new[1]])
        assert store.get([ids[0]])[0].pose == recs[0].pose  # nothing changed
        with pytest.raises(InputError, match="poses"):
            store.set_poses([ids[0]], [])
        assert store.set_poses(ids, new) == len(ids)
        for attempt in range(2):
            got = store.get(ids, with_embeddings=True)
            assert [g.pose for g in got] == new
            assert [(g.t, g.ocr_text, g.source) for g in got] == [(r.t, r.ocr_text, r.source) for r in recs]
            assert np.allclose(
                np.stack([g.embedding for g in got]),
                emb / np.linalg.norm(emb, axis=1, keepdims=True),
                atol=1e-6,
            )
            near = store.nearest(100.0, 0.0, None, 10)
            d = {r.id: float(np.hypot(p.x - 100.0, p.y)) for r, p in zip(recs, new, strict=True)}
            assert [i for i, _ in near] == sorted(d, key=lambda i: (d[i], i))[:10]
            region = Filter(region=Region(100.0, 0.0, 5.0))
            assert store.select(region).tolist() == [i for i in ids if d[i] <= 5.0]
            assert store.stats()["x_max"] >= max(p.x for p in new) > 100
            if attempt == 0:
                store.close()
                store = open_fn(dim=DIM)
    finally:
        store.close()


def _turn(zw: tuple[float, float], half: float) -> tuple[float, float]:
    """A yaw-only quaternion's (z, w) turned by 2 * half about z."""
    z, w = zw
    return (float(np.sin(half) * w + np.cos(half) * z), float(np.cos(half) * w - np.sin(half) * z))
