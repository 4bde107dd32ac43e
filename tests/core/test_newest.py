"""The latest mode's few searches against a brute-force reference (`ravenmem.memory.newest`).

Random memories: a robot drives up and down a corridor (so places are seen again and again), a
thing is in view at a few spots, seen far more often than one search returns (pool 40, up to
`MAX_K` = 1000 per exact window) and, in the hard case, better in its old sightings than in
its newest ones, so a search's best matches are all old. The reference scores every stored
vector: the newest sighting (and each place's) must be what brute force says, on the exact
index and on the IVF one (8-bit codes, filtered searches).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pytest

import ravenmem
from ravenmem.memory.newest import Later, newest_sightings
from ravenmem.memory.views import ChangeConfig, _disc, overlapping_poses
from ravenmem.store.base import Cameras
from ravenmem.types import Frame, Pose, Region

T0 = 1_700_000_000.0
DIM = 32
N = 6000


class Thing:
    """Texts are the thing's direction; pictures are never embedded (vectors are given)."""

    name = "test-thing"
    dim = DIM

    def __init__(self, u: np.ndarray) -> None:
        self.u = u

    def embed_texts(self, texts: Sequence[str]) -> np.ndarray:
        return np.stack([self.u for _ in texts])

    def embed_images(self, images: Sequence[np.ndarray]) -> np.ndarray:
        raise NotImplementedError("vectors are given")


def world(seed: int, old_better: bool) -> tuple[list[Pose], np.ndarray, np.ndarray]:
    """Poses (a 30 m corridor driven back and forth, 0.5 m a step), embeddings, thing direction.
    The thing sits at x = 3 until 60 % of the time, then at x = 21 (and at x = 12 on a few
    passes); near it a view shows it, strongly (old spot, when `old_better`) or less so."""
    rng = np.random.default_rng(seed)
    u = rng.normal(size=DIM).astype(np.float32)
    u /= np.linalg.norm(u)
    noise = rng.normal(size=(N, DIM)).astype(np.float32)
    noise -= np.outer(noise @ u, u)  # no view shows the thing by chance
    noise /= np.linalg.norm(noise, axis=1, keepdims=True)
    poses, emb = [], noise.copy()
    for i in range(N):
        lap, at = divmod(i, 60)
        x = 0.5 * (at if lap % 2 == 0 else 59 - at)
        yaw = 0.0 if lap % 2 == 0 else np.pi
        poses.append(Pose(x, 0.0, 0.5, yaw))
        spot = 3.0 if i < 0.6 * N else 21.0
        extra = 12.0 if rng.random() < 0.01 else None
        strength = (0.9 if old_better else 0.7) if spot == 3.0 else 0.75
        if abs(x - spot) <= 1.0 or (extra is not None and abs(x - extra) <= 1.0):
            v = strength * u + np.sqrt(1 - strength**2) * noise[i]
            emb[i] = v / np.linalg.norm(v)
    return poses, emb, u


@pytest.fixture(scope="module", params=[(0, True, "flat"), (1, False, "flat"), (2, True, "ivf")])
def memory(request, tmp_path_factory):
    seed, old_better, kind = request.param
    poses, emb, u = world(seed, old_better)
    mem = ravenmem.create(
        tmp_path_factory.mktemp("newest") / "m.mem", embedder=Thing(u), ocr=False, thumb_size=0
    )
    img = np.zeros((2, 2, 3), np.uint8)
    mem.add_frames([Frame(img, T0 + i, poses[i], "t", i) for i in range(N)], embeddings=emb)
    if kind == "ivf":
        mem.store.ann_threshold = 1000
        mem.store.rebuild_index()
        assert mem.store.index_kind == "ivf"
    mem.old_better = old_better  # type: ignore[attr-defined]
    yield mem, emb, u
    mem.close()


def brute(mem, emb: np.ndarray, u: np.ndarray):
    """Every memory's record and exact score, chronological."""
    recs = sorted(mem.all_records(), key=lambda r: (r.t, r.id))
    by_id = {r.id: r for r in recs}
    order = [r.id for r in recs]
    scores = {i: float(emb[by_id[i].frame_index] @ u) for i in order}
    return recs, scores


@pytest.mark.parametrize("after_frac", [0.0, 0.3, 0.59, 0.95])
def test_the_newest_sighting_is_the_brute_force_one(memory, after_frac) -> None:
    mem, emb, u = memory
    recs, scores = brute(mem, emb, u)
    thr = 0.5
    after = T0 + after_frac * N
    truth = [r for r in recs if r.t >= after and scores[r.id] >= thr]
    assert len(truth) > (40 if after_frac < 0.9 else 10)  # mostly more than one search returns
    got, complete = newest_sightings(mem, u, after, None, thr, pool=40)
    assert len(got), "a sighting exists"
    assert got.key(-1) == (truth[-1].t, truth[-1].id)
    assert all(scores[i] >= thr for i in got.ids.tolist())
    # the window it read is complete: every sighting from its first one on is there, and from
    # the time it says on (what the latest mode answers later questions inside it from)
    assert got.ids.tolist() == [r.id for r in truth if (r.t, r.id) >= got.key(0)]
    assert complete is not None and complete <= got.t[0]
    assert [i for i in got.ids.tolist() if mem.store.cameras_of([i]).t[0] >= complete] == [
        r.id for r in truth if r.t >= complete
    ]


@pytest.mark.parametrize("spot", [3.0, 12.0, 21.0])
def test_later_sightings_of_a_place_reach_its_newest_and_are_kept(memory, spot) -> None:
    mem, emb, u = memory
    recs, scores = brute(mem, emb, u)
    thr = 0.5
    region = Region(spot, 0.0, 1.5)
    inside = [r for r in recs if abs(r.pose.x - spot) <= 1.5 and scores[r.id] >= thr]
    assert inside
    later = Later(mem, u, thr, None, pool=40, steps=8, margin=1.5)
    got, complete = later.find(inside[0].t, region, lambda hits: np.ones(len(hits), bool))
    assert got.key(-1) == (inside[-1].t, inside[-1].id)
    assert set(got.ids.tolist()) <= {r.id for r in inside}
    if complete:  # said to be all of them: brute force's
        assert got.ids.tolist() == [r.id for r in inside]
    none, complete = later.find(inside[-1].t + 0.5, region, lambda hits: np.ones(len(hits), bool))
    assert len(none) == 0 and complete  # nothing after the newest, and that is sure
    # asked again inside what was searched, from when on it holds every sighting: the same
    # answer as brute force, without a search
    searches, (complete_from, _, _) = len(later.known), later.known[0]
    inner = Region(spot + 0.5, 0.0, 1.0)
    again, complete = later.find(complete_from, inner, lambda hits: hits.ids % 2 == 0)
    assert complete
    want = [
        r.id
        for r in recs
        if r.t >= complete_from and scores[r.id] >= thr and abs(r.pose.x - spot - 0.5) <= 1.0
    ]
    assert want and again.ids.tolist() == [i for i in want if i % 2 == 0]
    assert len(later.known) == searches


def test_later_sightings_cut_short_say_so(memory) -> None:
    """A search that stops at its best `pool` (one step, more sightings than that) does not
    say it holds every sighting: `grow` would otherwise take the place's later views for
    views without the thing unscored."""
    mem, emb, u = memory
    recs, scores = brute(mem, emb, u)
    inside = [r for r in recs if abs(r.pose.x - 3.0) <= 1.5 and scores[r.id] >= 0.5]
    assert len(inside) > 5
    got, complete = Later(mem, u, 0.5, None, pool=5, steps=1, margin=1.5).find(
        inside[0].t, Region(3.0, 0.0, 1.5), lambda hits: np.ones(len(hits), bool)
    )
    assert 0 < len(got) < len(inside) and not complete


def test_last_seen_ends_every_place_at_its_newest_sighting(memory) -> None:
    mem, emb, u = memory
    recs, scores = brute(mem, emb, u)
    s = ChangeConfig(pool=40)
    w = mem.last_seen(vector=u, config=s)
    truth = [r for r in recs if scores[r.id] >= w.threshold]
    newest = max((p.last for p in w.places), key=lambda r: (r.t, r.id))
    assert (newest.t, newest.id) == (truth[-1].t, truth[-1].id)
    assert abs(w.now.last.pose.x - 21.0) <= 1.0 and w.status != "gone"
    for p in w.places:  # nothing later looks at the place's views and shows the thing
        _, cams = _disc(p, s)
        later = [
            r
            for r in truth
            if (r.t, r.id) > p.found.key(-1) and overlapping_poses(Cameras.of([r]).poses, cams, s)[0]
        ]
        assert later == [], f"place {p.index} stops at m{p.last.id}, m{later[0].id} is later"
    old = [p for p in w.places if abs(p.last.pose.x - 3.0) <= 1.0]
    assert all(p.verdict == "moved" for p in old)
    assert old or not mem.old_better  # the best matches are at the old spot: it is a place


def test_the_newest_window_answers_later_asks_inside_it(memory, monkeypatch) -> None:
    """`Later.knows` the newest window's sightings (every one from its start on, anywhere):
    a place asking from inside that range is answered from them without a search, the same
    as brute force; one asking from before it searches."""
    mem, emb, u = memory
    recs, scores = brute(mem, emb, u)
    thr = 0.5
    recent, complete = newest_sightings(mem, u, T0 + 0.9 * N, None, thr, pool=40)
    assert complete is not None and len(recent)
    later = Later(mem, u, thr, None, pool=40, steps=8, margin=1.5)
    later.knows(complete, None, recent)
    searches: list[object] = []
    search = mem.store.search_vector
    monkeypatch.setattr(mem.store, "search_vector", lambda *a, **kw: searches.append(a) or search(*a, **kw))
    spot = float(recent.poses[0, 0])
    got, sure = later.find(complete, Region(spot, 0.0, 1.5), lambda hits: np.ones(len(hits), bool))
    want = [r.id for r in recs if r.t >= complete and scores[r.id] >= thr and abs(r.pose.x - spot) <= 1.5]
    assert sure and got.ids.tolist() == want and want and not searches
    later.find(complete - 5.0, Region(spot, 0.0, 1.5), lambda hits: np.ones(len(hits), bool))
    assert searches
