"""A floor search in a disc tests the positions of the IVF lists that can matter only
(`ravenmem.store._boxes`): the same hits as testing every position of the time range, as the
robot adds memories, forgets some, and imports more."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ravenmem.store.local import LocalStore
from ravenmem.types import Filter, Region
from tests.store.store_helpers import ivf_stream

DIM = 32


def test_a_disc_search_with_a_floor_finds_what_the_columns_find(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    store, emb, recs = ivf_stream(tmp_path / "m", 4_000, 3_000, DIM)
    assert isinstance(store, LocalStore)
    boxed = LocalStore._accepted
    tested: list[int] = []

    def columns(
        self: LocalStore, filt: Filter, q: np.ndarray, floor: float | None, exact: bool
    ) -> tuple[np.ndarray, bool]:
        return self._columns().select_ids(filt)

    def counted(
        self: LocalStore, filt: Filter, q: np.ndarray, floor: float | None, exact: bool
    ) -> tuple[np.ndarray, bool]:
        got = boxed(self, filt, q, floor, exact)
        tested.append(len(got[0]))
        return got

    rng = np.random.default_rng(5)

    def same(rows: range) -> int:
        """Searches around memories of `rows`: with boxes and through the columns, equal."""
        found = 0
        for i in rng.choice(rows, 6, replace=False):
            p = recs[i].pose
            for r, after in ((2.0, None), (4.0, recs[rows.start].t)):
                filt = Filter(after=after, region=Region(p.x, p.y, r))
                q = (emb[i] + 0.2 * rng.normal(size=DIM) / np.sqrt(DIM)).astype(np.float32)
                monkeypatch.setattr(LocalStore, "_accepted", columns)
                full = store.search_vector(q, 50, filt)
                floor = full[min(4, len(full) - 1)][1] - 1e-6
                want = store.search_vector(q, 50, filt, min_score=floor)
                monkeypatch.setattr(LocalStore, "_accepted", counted)
                got = store.search_vector(q, 50, filt, min_score=floor)
                assert got == want  # the same hits, in the same order, with the same scores
                assert [i for i, _ in got] == [i for i, sc in full if sc >= floor]
                found += len(got)
        return found

    try:
        assert same(range(0, 3_000)) >= 30
        accepted = len(store.select(Filter(region=Region(recs[10].pose.x, recs[10].pose.y, 4.0))))
        assert tested and min(tested) < accepted  # fewer positions than the disc holds were tested
        store.add(recs[3_000:3_400], emb[3_000:3_400])  # new views: their lists' boxes are read again
        assert same(range(3_000, 3_400)) >= 30
        gone = store.select(Filter(after=recs[3_100].t, before=recs[3_200].t))
        store.delete(gone.tolist())
        for i in range(3_100, 3_200, 20):
            p = recs[i].pose
            hits = store.search_vector(emb[i], 20, Filter(region=Region(p.x, p.y, 1.0)), min_score=0.0)
            assert not set(gone.tolist()) & {h for h, _ in hits}
        store.add_many([(recs[3_400:4_000], emb[3_400:4_000])])  # an import: every add goes through
        assert same(range(3_400, 4_000)) >= 30
    finally:
        store.close()
