"""The four searches of a memory: by text (fused with OCR), image, time and position.

Each turns a query into a store call (a vector, a time walk, a nearest-position search) under
the filters of `Core.make_filter`, and returns `Hit`s best first (or in time order), with the
count and span of consolidated memories. `diverse` keeps one hit per moment and place
(`ravenmem.memory.diversity`); `check_k` bounds every result count.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..embed.ocr import OCR_WEIGHT, ocr_terms
from ..errors import EmptyMemoryError, InputError
from ..imageio import read_image
from ..types import Filter, Hit, MemoryRecord, check_picture
from .core import Core, check_text, finite
from .diversity import top_hits
from .protocol import MAX_K, Near, TimeLike, check_k


class Search(Core):
    """The search methods of `Memory`."""

    def _require_nonempty(self) -> None:
        if self.count() == 0:
            raise EmptyMemoryError(f"memory {self.path} is empty: ingest something first")

    def _hits(self, scored: Sequence[tuple[int, float]], kind: str = "score") -> list[Hit]:
        recs = {r.id: r for r in self.stored([i for i, _ in scored])}
        if kind == "distance":
            hits = [Hit(memory=recs[i], distance=float(d)) for i, d in scored if i in recs]
        else:
            hits = [Hit(memory=recs[i], score=float(s)) for i, s in scored if i in recs]
        return self.grouped(hits)

    def search_text(
        self,
        query: str,
        k: int = 5,
        after: TimeLike = None,
        before: TimeLike = None,
        near: Near | None = None,
        diverse: bool = True,
    ) -> list[Hit]:
        """Cosine between the text and stored images, fused with OCR matches; best first.
        `diverse`: no two hits from the same moment and place (ravenmem.diversity)."""
        return self.search_texts([query], k, after, before, near, diverse=diverse)[0]

    def search_texts(
        self,
        queries: Sequence[str],
        k: int = 5,
        after: TimeLike = None,
        before: TimeLike = None,
        near: Near | None = None,
        ocr: bool = True,
        diverse: bool = True,
    ) -> list[list[Hit]]:
        """`search_text` for many queries with one batched text encoding (reasoners that try
        several phrasings of a question use this). `ocr=False` leaves out the OCR channel."""
        if isinstance(queries, str) or not queries:
            raise InputError("search_texts: expected a list of text queries")
        for q in queries:
            check_text(q)
        k = check_k(k)
        self._require_nonempty()
        filt = self.make_filter(after, before, near)
        use_ocr = ocr and self.ocr_enabled
        vecs = self.embedder.embed_texts(list(queries))
        return [self._text_hits(query, q, k, filt, use_ocr, diverse) for query, q in zip(queries, vecs)]

    def search_vectors(self, vectors: np.ndarray, k: int = 5, diverse: bool = True) -> list[list[Hit]]:
        """`search_texts(texts, k, ocr=False, diverse=diverse)` for texts already embedded by this
        memory's embedder (one row each): the offline reasoner keeps its decoys' vectors, so a
        recalibration is only the searches."""
        vecs = np.asarray(vectors)  # as given: the rows `search_texts` would search
        if vecs.ndim != 2 or vecs.shape[0] == 0:
            raise InputError("search_vectors: expected a non-empty 2-D array of query vectors")
        k = check_k(k)
        self._require_nonempty()
        filt = self.make_filter(None, None, None)
        if diverse:
            return [self._text_hits("", q, k, filt, False, diverse) for q in vecs]
        # every query's k best as `_fused` ranks them, the records read once for all queries
        ranked = [_ranked(dict(self.store.search_vector(q, k, filt)), k) for q in vecs]
        recs = {r.id: r for r in self.stored(sorted({i for rows in ranked for _, i in rows}))}
        return [
            self.grouped([Hit(memory=recs[i], score=sc, ocr_match=False) for sc, i in rows if i in recs])
            for rows in ranked
        ]

    def _text_hits(
        self, query: str, q: np.ndarray, k: int, filt: Filter, use_ocr: bool, diverse: bool = True
    ) -> list[Hit]:
        return top_hits(lambda n: self._fused(query, q, n, filt, use_ocr), k, diverse, self.count())

    def _fused(self, query: str, q: np.ndarray, k: int, filt: Filter, use_ocr: bool) -> list[Hit]:
        scored = dict(self.store.search_vector(q, max(k, 1) * (3 if use_ocr else 1), filt))
        ocr = dict(self.store.search_text(ocr_terms(query), max(k, 1) * 3, filt)) if use_ocr else {}
        missing = [i for i in ocr if i not in scored]
        if missing:
            for r in self.store.get(missing, with_embeddings=True):
                assert r.embedding is not None
                scored[r.id] = float(np.dot(r.embedding, q))
        hits = self._hits([(i, s) for s, i in _ranked(scored, k, ocr)])
        for h in hits:
            h.ocr_match = h.memory.id in ocr
        return hits

    def search_image(
        self,
        image: np.ndarray | str | os.PathLike[str] | None = None,
        k: int = 5,
        after: TimeLike = None,
        before: TimeLike = None,
        near: Near | None = None,
        memory_id: int | None = None,
        diverse: bool = True,
    ) -> list[Hit]:
        """Memories that look like a query image (cosine), best first.

        The query is a picture (an array or an image file) or, with `memory_id`, a stored memory:
        "more views like memory 12", which is how an agent follows up on a promising frame. The
        memory itself is left out of its own results. `diverse`: no two hits from the same
        moment and place (ravenmem.diversity; views of the memory's own moment still count).
        """
        k = check_k(k)
        self._require_nonempty()
        if (image is None) == (memory_id is None):
            raise InputError("search_image needs either an image or a memory_id, not both")
        filt = self.make_filter(after, before, near)
        if memory_id is not None:
            rec = self.embedded(memory_id)
            q = rec.embedding
            assert q is not None
        else:
            assert image is not None
            img = read_image(Path(image)) if isinstance(image, (str, os.PathLike)) else image
            q = self.embedder.embed_images([check_picture(img, "query image")])[0]
        skip = -1 if memory_id is None else rec.id

        def ranked(n: int) -> list[Hit]:  # equal scores: the earlier memory first, as in text search
            scored = sorted(self.store.search_vector(q, n + 1, filt), key=lambda p: (-p[1], p[0]))
            return self._hits([(i, s) for i, s in scored if i != skip][:n])

        return top_hits(ranked, k, diverse, self.count())

    def search_time(
        self,
        t: TimeLike,
        k: int = 5,
        after: TimeLike = None,
        before: TimeLike = None,
        near: Near | None = None,
        centred: bool = False,
    ) -> list[Hit]:
        """The k memories from time t onwards, in forward chronological order.

        The paper's time tool looks forward from t; `centred=True` returns the k memories around
        t instead (half before, half from t on), still in chronological order.
        """
        k = check_k(k)
        self._require_nonempty()
        t0 = self.parse_time(t)
        filt = self.make_filter(after, before, near)
        if not centred:
            return self.grouped([Hit(memory=r) for r in self.store.by_time(t0, k, filt)])
        later = self.store.by_time(t0, k, filt)
        earlier = self._before(t0, k, filt)
        n_before = min(len(earlier), max(k // 2, k - len(later)))
        picked = earlier[len(earlier) - n_before :] + later[: k - n_before]
        return self.grouped([Hit(memory=r) for r in picked])

    def _before(self, t: float, k: int, filt: Filter) -> list[MemoryRecord]:
        """Up to k memories strictly before t, chronological. The store only looks forward, so
        this searches for a window [t - w, t) that holds at least k memories but fewer than the
        page it reads (bisection on w), reading at most 4k rows per step."""
        if k <= 0:
            return []
        start, _ = self.time_span()
        page = 4 * k
        w_lo, w_hi, w = 0.0, float("inf"), max((t - start) / max(self.count(), 1) * k, 1e-3)
        before: list[MemoryRecord] = []
        for _ in range(64):
            recs = self.store.by_time(max(start, t - w), page, filt)
            before = [r for r in recs if r.t < t]
            if len(recs) == page and len(before) == page:  # the page ended before t: too wide
                w_hi, w = w, (w_lo + w) / 2
            elif len(before) >= k or t - w <= start:
                break
            else:
                w_lo, w = w, (w * 4 if w_hi == float("inf") else (w + w_hi) / 2)
        return before[-k:]

    def search_position(
        self,
        x: float,
        y: float,
        z: float | None = None,
        k: int = 5,
        radius: float | None = None,
        after: TimeLike = None,
        before: TimeLike = None,
    ) -> list[Hit]:
        """The k memories taken nearest to (x, y[, z]), nearest first; planar when z is None."""
        k = check_k(k)
        x, y = finite("x", x), finite("y", y)
        z = None if z is None else finite("z", z)
        if radius is not None and not finite("radius", radius) > 0:
            raise InputError(f"radius must be > 0, got {radius}")
        self._require_nonempty()
        filt = self.make_filter(after, before)
        r = None if radius is None else float(radius)
        want = k
        while True:  # more when memories another process forgot were skipped (`stored`)
            scored = self.store.nearest(x, y, z, want, r, filt)
            hits = self._hits(scored, kind="distance")
            if len(hits) >= k or len(scored) < want or want >= MAX_K:
                return hits[:k]
            want = min(MAX_K, 4 * want)


def _ranked(scored: dict[int, float], k: int, ocr: dict[int, float] | None = None) -> list[tuple[float, int]]:
    """(score, id) of the k best, an OCR match's weight added: best first; equal scores put the
    earlier memory first, however many candidates were fetched."""
    bonus = ocr or {}
    return sorted(
        ((float(s) + OCR_WEIGHT * bonus.get(i, 0.0), i) for i, s in scored.items()),
        key=lambda p: (-p[0], p[1]),
    )[:k]
