"""The local store's tail: the newest memories' exact vectors in RAM, used by exact searches
over the recent past (`ravenmem.store._tail`)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from ravenmem.store import _sql, _tail
from ravenmem.store._tail import Tail
from ravenmem.store.local import LocalStore
from ravenmem.types import Filter, Region
from tests.store.store_helpers import ivf_stream

DIM = 32


def test_a_tail_keeps_the_newest_and_says_what_it_covers() -> None:
    rng = np.random.default_rng(1)
    vecs = rng.normal(size=(30, 4)).astype(np.float32)
    ids = np.arange(1, 31, dtype=np.int64)
    tail = Tail(4, 0, ids[:5], vecs[:5], budget=8 * 4 * 8)  # 8 memories at dim 4
    assert tail.cap == 8 and tail.ids.tolist() == [1, 2, 3, 4, 5]
    for s in range(5, 30, 3):  # appends past twice the capacity move the buffer
        tail.append(ids[s : s + 3], vecs[s : s + 3])
        assert tail.ids[-1] == min(s + 3, 30) and len(tail.ids) >= min(8, s + 3)
        assert tail.ids.tolist() == list(range(tail.after + 1, int(tail.ids[-1]) + 1))
    assert (
        len(tail.ids) >= 8
        and tail.covers(np.array([tail.after + 1]))
        and not tail.covers(np.array([tail.after]))
    )
    q = rng.normal(size=4).astype(np.float32)
    got, sc = tail.scores(np.array([28, 29, 30, 31]), q)  # 31 is not stored: left out
    assert got.tolist() == [28, 29, 30] and np.allclose(sc, vecs[27:30] @ q)
    for want in ([27, 28, 29], [27, 29, 30], [30], [26, 28, 30]):  # runs (read in place) or not
        got, sc = tail.scores(np.array(want), q)
        assert got.tolist() == want and np.allclose(sc, vecs[np.array(want) - 1] @ q)
    tail.append(np.arange(31, 51, dtype=np.int64), rng.normal(size=(20, 4)).astype(np.float32))
    assert tail.ids.tolist() == list(range(43, 51)) and tail.after == 42  # a batch over capacity


def brute(emb: np.ndarray, alive: np.ndarray, q: np.ndarray, ok: np.ndarray) -> list[int]:
    scores = emb @ (q / np.linalg.norm(q))
    rows = np.flatnonzero(ok & alive)
    return [int(i) + 1 for i in rows[np.lexsort((rows, -scores[rows]))]]


def test_exact_searches_of_the_recent_past_are_scored_from_ram(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """An exact search whose window lies in the newest memories reads no vector from SQLite
    and gives the scan's answer; one reaching further back scans; memories added or deleted
    since are in or out of the answer at once."""
    monkeypatch.setattr(_tail, "TAIL_BYTES", 500 * 8 * DIM)  # the newest 500 of 3,000
    store, emb, recs = ivf_stream(tmp_path / "m", 3_600, 3_000, DIM)
    assert isinstance(store, LocalStore)
    read: list[int] = []
    for name in ("fetch_vectors", "read_vectors"):
        real = getattr(_sql, name)
        monkeypatch.setattr(_sql, name, lambda *a, _f=real, **kw: read.append(1) or _f(*a, **kw))
    alive = np.zeros(3_600, bool)
    alive[:3_000] = True
    t = np.array([r.t for r in recs])
    rng = np.random.default_rng(3)

    def check(lo: int, hi: int, region: Region | None = None) -> list[int]:
        filt = Filter(after=float(t[lo]), before=float(t[hi]), region=region)
        ok = (t >= t[lo]) & (t <= t[hi])
        if region is not None:
            ok &= np.array([filt.accepts(r) for r in recs])
        q = (emb[hi] + 0.3 * rng.normal(size=DIM) / np.sqrt(DIM)).astype(np.float32)
        read.clear()
        got = store.search_vector(q, 1_000, filt, exact=True)
        assert [i for i, _ in got] == brute(emb, alive, q, ok)
        floor = got[min(5, len(got) - 1)][1] - 1e-6
        assert [i for i, _ in store.search_vector(q, 1_000, filt, exact=True, min_score=floor)] == [
            i for i, sc in got if sc >= floor
        ]
        return list(read)

    try:
        check(2_700, 2_999)  # loads the tail: one read of the newest vectors
        assert check(2_600, 2_999) == [] and check(2_900, 2_950, Region(0.0, 0.0, 50.0)) == []
        assert check(2_000, 2_999) != []  # reaches before the tail: read from SQLite
        store.add(recs[3_000:3_200], emb[3_000:3_200])  # the robot goes on
        alive[3_000:3_200] = True
        assert check(3_000, 3_199) == []
        gone = [3_150, 3_151, 3_190]
        assert store.delete([i + 1 for i in gone]) == 3
        alive[gone] = False
        assert check(3_100, 3_199) == []
        store.add(recs[3_200:3_600], emb[3_200:3_600])  # past the tail's buffer: the oldest go
        alive[3_200:3_600] = True
        assert check(3_300, 3_599) == [] and check(2_900, 3_599) != []
    finally:
        store.close()
