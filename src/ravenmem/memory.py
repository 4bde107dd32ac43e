"""The `Memory` facade: one folder on disk that holds what a robot saw, where and when.

A memory folder contains `memory.json` (the manifest, `ravenmem.manifest`: embedder name and
dim, store URI, thumbnail and OCR settings, ingest history), the store's files (for the embedded
store) and `thumbs/` (JPEG thumbnails). The facade turns user queries into vectors, fuses the OCR
channel, resolves time expressions and hands out `Hit`s; the store does the indexing.

Nothing read from a memory reaches outside its folder: the manifest is checked before the store
is opened, the store must live in the folder (or be the server the user named at create time),
and a record's image path is only followed when it stays inside the folder.
"""

from __future__ import annotations

import logging
import math
import os
import shutil
import threading
import time
import uuid
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from . import diversity, recovery
from .embed.base import Embedder, create_embedder
from .embed.ocr import OCR_WEIGHT, ocr_terms
from .errors import EmbedderMismatchError, EmptyMemoryError, InputError, MemoryBusyError
from .imageio import read_image, write_jpeg
from .lifelong import sidecars
from .lifelong.groups import GroupView, annotate
from .lock import LOCK_FILE, WriterLock
from .manifest import (
    FORMAT_VERSION,
    MANIFEST,
    Manifest,
    check_name,
    check_trusted,
    confine,
    store_for_create,
    store_kind,
    trust_store,
)
from .store.base import Store, open_store
from .timeparse import TimeContext, parse_time
from .tools import MAX_K, check_k
from .types import Filter, Frame, Hit, MemoryRecord, Pose, Region

if TYPE_CHECKING:
    from .changes import ChangeSettings, Whereabouts
    from .lifelong import ConsolidateReport, ForgetReport
    from .query import Query

__all__ = ["FORMAT_VERSION", "MANIFEST", "Memory", "create", "open"]
log = logging.getLogger(__name__)
Near = tuple[float, float, float]
TimeLike = float | int | str | None


class Memory:
    """A visual memory: add frames, then search by text, image, time or position.

    Use `ravenmem.create(path)` for a new memory and `ravenmem.open(path)` for an existing one.
    The embedder is loaded on first use, so time and position queries start instantly.
    `external_images=True` lets `image_file`/`load_image` follow absolute image paths (memories
    built with `thumb_size=0` store the original frames' paths); off by default, because a
    memory folder from elsewhere could name any file on this machine.
    """

    def __init__(
        self,
        path: Path,
        manifest: Manifest,
        store: Store,
        embedder: Embedder | None,
        external_images: bool = False,
    ) -> None:
        self.path = path
        self.manifest = manifest
        self.store = store
        self.external_images = external_images
        self._embedder = embedder
        self._lock = threading.RLock()
        self._ocr: Any = None
        self._span: tuple[float, float] | None = None
        self._created: _Created | None = None
        self._closed = False
        self._writer = WriterLock(path)
        self._groups = GroupView(path)  # consolidated memories: count and span (ravenmem.lifelong)

    # ---------------------------------------------------------------- properties
    @property
    def embedder(self) -> Embedder:
        with self._lock:
            if self._embedder is None:
                self._embedder = create_embedder(self.manifest.embedder)
                _check_embedder(self._embedder, self.manifest, self.path)
            return self._embedder

    @property
    def ocr_enabled(self) -> bool:
        return self.manifest.ocr

    @property
    def thumb_size(self) -> int:
        return self.manifest.thumb_size

    # ---------------------------------------------------------------- writing
    def add(self, image: np.ndarray, pose: Pose, t: float, source: str = "live", frame_index: int = 0) -> int:
        """Append one observation (thread-safe; another thread may search meanwhile)."""
        return self.add_frames([Frame(image=image, t=t, pose=pose, source=source, index=frame_index)])[0]

    def add_frames(self, frames: Sequence[Frame], embeddings: np.ndarray | None = None) -> list[int]:
        """Embed, OCR, thumbnail and store frames; durable when this returns.

        `embeddings` may be passed when the caller already computed them (the ingest pipeline
        does, for novelty filtering), so that frames are never embedded twice. The first write
        takes the writer lock (`acquire_writer`) without waiting.
        """
        if not frames:
            return []
        self._require_writer()
        for f in frames:
            _validate_frame(f)
        if embeddings is None:
            embeddings = self.embedder.embed_images([f.image for f in frames])
        embeddings = np.asarray(embeddings, dtype=np.float32)
        if embeddings.shape != (len(frames), self.dim):
            raise InputError(
                f"embeddings have shape {embeddings.shape}, expected ({len(frames)}, {self.dim})"
            )
        texts = [self._read_text(f.image) for f in frames] if self.ocr_enabled else [""] * len(frames)
        paths = [self._thumb_name(f) for f in frames]
        # thumbnails go to disk before their records commit; the journal lets the next writer
        # delete them if this process dies in between (ravenmem.recovery)
        journal = None
        if self.thumb_size > 0:
            entries = [(p or "", f.source, int(f.index), float(f.t)) for p, f in zip(paths, frames)]
            journal = recovery.begin(self.path, entries)
        try:
            records = []
            for f, text, rel in zip(frames, texts, paths):
                assert f.pose is not None
                records.append(
                    MemoryRecord(
                        id=-1,
                        t=float(f.t),
                        pose=f.pose,
                        source=f.source,
                        frame_index=int(f.index),
                        image_path=self._write_thumb(f, rel),
                        ocr_text=text,
                    )
                )
            with self._lock:
                ids = self.store.add(records, embeddings)
                self._span = None
        except BaseException:
            if journal is not None:  # delete what the store did not take (it may have: check)
                recovery.settle(self.path, self.store, journal)
            raise
        if journal is not None:
            recovery.end(journal)
        return ids

    def import_embeddings(
        self, batches: Iterable[tuple[Sequence[MemoryRecord], np.ndarray]], resume: str | None = None
    ) -> int:
        """Bulk-add memories whose embeddings were computed elsewhere (by this memory's
        embedder; no image is read, no thumbnail written, OCR text comes with the records).

        Each batch is committed in one transaction; with `resume` (a name for this import) a
        rerun after a crash skips what was committed. Returns how many memories were added;
        they are searchable when this returns. See `Store.add_many`. Takes the writer lock like
        the other writes.
        """
        self._require_writer()

        def checked() -> Iterator[tuple[Sequence[MemoryRecord], np.ndarray]]:
            for records, emb in batches:
                if np.ndim(emb) != 2 or np.shape(emb)[1] != self.dim:
                    raise InputError(
                        f"embeddings have shape {np.shape(emb)}, expected (N, {self.dim}) for this memory's embedder"
                    )
                yield records, emb

        try:
            return self.store.add_many(checked(), resume=resume)
        finally:
            with self._lock:
                self._span = None

    def _read_text(self, image: np.ndarray) -> str:
        if self._ocr is None:
            from .embed.ocr import OcrReader

            self._ocr = OcrReader()
        return str(self._ocr.read(image))

    def _thumb_name(self, f: Frame) -> str | None:
        """The thumbnail's path relative to the folder (None when thumbnails are off)."""
        if self.thumb_size <= 0:
            return None
        return f"thumbs/{int(f.t * 1000):015d}_{uuid.uuid4().hex[:8]}.jpg"

    def _write_thumb(self, f: Frame, rel: str | None) -> str | None:
        if rel is None:
            return str(Path(f.path).resolve()) if f.path else None
        write_jpeg(
            self.path / rel,
            f.image,
            max_side=self.thumb_size,
            quality=self.manifest.thumb_quality,
        )
        return rel

    def record_ingest(self, report: dict[str, Any]) -> None:
        """Append an ingest run's counts to the manifest (frames seen/kept, raw bytes)."""
        self._require_writer()
        with self._lock:
            self.manifest.ingests.append(report)
            self._save_manifest()

    @property
    def name(self) -> str:
        """The display name the user gave this memory (`set_name`), else the folder's name."""
        return self.manifest.name or self.path.name

    def set_name(self, name: str) -> None:
        """Give the memory a display name (kept in its manifest; "" clears it). The service's
        page and `ravenmem info` show it; the folder keeps its own name."""
        name = check_name(name.strip() if isinstance(name, str) else name)  # before any write
        self._require_writer()
        with self._lock:
            self.manifest.name = name
            self._save_manifest()

    # ---------------------------------------------------------------- forgetting
    def forget(
        self,
        before: TimeLike = None,
        after: TimeLike = None,
        region: Near | None = None,
        ids: Iterable[int] | None = None,
        dry_run: bool = False,
    ) -> ForgetReport:
        """Remove memories for good: store rows, index entries, thumbnails, sidecar rows.

        Selectors combine (a memory must match every one given): `before`/`after` are time
        expressions (inclusive, as in the search filters), `region` an (x, y, radius m) disc,
        `ids` memory ids. At least one is required; selecting nothing is not an error (the
        report says 0). Crash-safe: a killed process leaves all of them or none, and the next
        writer removes any thumbnail left over (`ravenmem.lifelong.forget`). Takes the writer
        lock; `dry_run=True` only reports what would go.
        """
        from .lifelong.forget import forget

        return forget(self, before=before, after=after, region=region, ids=ids, dry_run=dry_run)

    def consolidate(
        self,
        budget: int | None = None,
        max_similarity: float | None = None,
        max_distance: float = 1.0,
        max_gap: float | None = None,
        dry_run: bool = False,
    ) -> ConsolidateReport:
        """Merge runs of near-duplicate memories (neighbours in time, within `max_distance`
        metres, most similar first) into one representative that keeps their count and time
        span, until no neighbours are more similar than `max_similarity` and/or at most
        `budget` memories remain. Crash-safe like `forget`; see `ravenmem.lifelong.consolidate`.
        """
        from .lifelong.consolidate import consolidate

        return consolidate(self, budget, max_similarity, max_distance, max_gap, dry_run)

    def group(self, memory_id: int) -> tuple[int, float, float] | None:
        """(count, first_t, last_t) when the memory stands for several (consolidated), else None."""
        return self._groups.get(self.store).get(int(memory_id))

    # ---------------------------------------------------------------- the writer lock
    def acquire_writer(self, wait: bool | float = False) -> None:
        """Become the one writer of this memory folder (see `ravenmem.lock`), and clean up after
        a writer that was killed (`ravenmem.recovery`: unreferenced thumbnails, temp files).

        Writes take the lock by themselves, without waiting, the first time they run; call
        this first to wait for another writer (`wait=True`, or seconds), to fail before any
        work rather than at the first write, or to hold a memory for a service's lifetime.
        Held until `close()` or `release_writer()`; readers never need it. A refusal raises
        `MemoryBusyError` naming the holder's pid and command.
        """
        with self._lock:
            if self._writer.held:
                return
            if self._closed:
                raise InputError(f"memory {self.path} is closed")
            writer = WriterLock(self.path)
            writer.acquire(wait)
            try:
                # what this Memory read at open may be stale: another writer may have added
                # memories (the store hands out ids from its own count) or ingest records since.
                # Closed first: Milvus Lite serves one client per file.
                self.store.close()
                fresh = _open(self.path, None, self.external_images)
                self.store, self.manifest, self._span = fresh.store, fresh.manifest, None
            except BaseException:
                writer.release()
                raise
            self._adopt_writer(writer)

    def _adopt_writer(self, writer: WriterLock) -> None:
        """Hold `writer` (acquired before this Memory read the store) and clean up after a
        writer that was killed."""
        self._writer = writer
        try:
            recovery.recover(self.path, self.store)
            sidecars.recover(self.path, self.store)
        except BaseException:
            writer.release()
            raise

    def release_writer(self) -> None:
        """Let another process write (this Memory takes the lock again at its next write)."""
        with self._lock:
            self._writer.release()

    @property
    def is_writer(self) -> bool:
        return self._writer.held

    def _require_writer(self) -> None:
        if not self._writer.held:
            self.acquire_writer(wait=False)

    def _save_manifest(self) -> None:
        self.manifest.save(self.path)

    # ---------------------------------------------------------------- reading
    @property
    def dim(self) -> int:
        return self.manifest.dim

    def count(self) -> int:
        return self.store.count()

    def time_span(self) -> tuple[float, float]:
        """(first, last) timestamp; raises EmptyMemoryError on an empty memory."""
        with self._lock:
            if self._span is None:
                st = self.store.stats()
                if not st.get("count"):
                    raise EmptyMemoryError(f"memory {self.path} is empty: ingest something first")
                lo, hi = float(st["t_min"]), float(st["t_max"])  # type: ignore[arg-type]
                for _, first, last in self._groups.get(self.store).values():  # what merged memories saw
                    lo, hi = min(lo, first), max(hi, last)
                self._span = (lo, hi)
            return self._span

    def parse_time(self, expr: TimeLike) -> float:
        """Resolve a time expression (see ravenmem.timeparse) against this recording."""
        if expr is None:
            raise InputError("no time given")
        try:
            ctx: TimeContext | None = TimeContext(*self.time_span())
        except EmptyMemoryError:
            ctx = None
        return parse_time(expr, ctx)

    def make_filter(
        self, after: TimeLike = None, before: TimeLike = None, near: Near | None = None
    ) -> Filter:
        """A store filter from a time window (any time expression) and a disc (x, y, radius m)."""
        region = None
        if near is not None:
            try:
                x, y, r = (float(v) for v in near)
            except (TypeError, ValueError):
                raise InputError(f"near must be (x, y, radius) numbers, got {near!r}") from None
            if not all(math.isfinite(v) for v in (x, y, r)) or r <= 0:
                raise InputError(f"near must be finite (x, y, radius > 0), got {near!r}")
            region = Region(x, y, r)
        return Filter(
            after=None if after is None else self.parse_time(after),
            before=None if before is None else self.parse_time(before),
            region=region,
        )

    def _require_nonempty(self) -> None:
        if self.count() == 0:
            raise EmptyMemoryError(f"memory {self.path} is empty: ingest something first")

    def _hits(self, scored: Sequence[tuple[int, float]], kind: str = "score") -> list[Hit]:
        recs = {r.id: r for r in self.stored([i for i, _ in scored])}
        if kind == "distance":
            hits = [Hit(memory=recs[i], distance=float(d)) for i, d in scored if i in recs]
        else:
            hits = [Hit(memory=recs[i], score=float(s)) for i, s in scored if i in recs]
        return self._grouped(hits)

    def stored(self, ids: Sequence[int], with_embeddings: bool = False) -> list[MemoryRecord]:
        """The records of `ids` that are still stored, in the order given. A reader that opened
        the memory before another process ran `forget` or `consolidate` (a read-only service,
        `ravenmem mcp`) still has the removed memories in its index; they are skipped here
        rather than failing the search."""
        try:
            return self.store.get(list(ids), with_embeddings=with_embeddings)
        except KeyError:
            out: list[MemoryRecord] = []
            for i in ids:
                try:
                    out += self.store.get([i], with_embeddings=with_embeddings)
                except KeyError:
                    continue
            return out

    def _grouped(self, hits: list[Hit]) -> list[Hit]:
        """Hits with `count`/`span` set where a memory stands for several (consolidated)."""
        annotate(hits, self._groups.get(self.store))
        return hits

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
            _check_text(q)
        k = check_k(k)
        self._require_nonempty()
        filt = self.make_filter(after, before, near)
        use_ocr = ocr and self.ocr_enabled
        vecs = self.embedder.embed_texts(list(queries))
        return [self._text_hits(query, q, k, filt, use_ocr, diverse) for query, q in zip(queries, vecs)]

    def _text_hits(
        self, query: str, q: np.ndarray, k: int, filt: Filter, use_ocr: bool, diverse: bool = True
    ) -> list[Hit]:
        return diversity.top_hits(lambda n: self._fused(query, q, n, filt, use_ocr), k, diverse, self.count())

    def _fused(self, query: str, q: np.ndarray, k: int, filt: Filter, use_ocr: bool) -> list[Hit]:
        scored = dict(self.store.search_vector(q, max(k, 1) * (3 if use_ocr else 1), filt))
        ocr = dict(self.store.search_text(ocr_terms(query), max(k, 1) * 3, filt)) if use_ocr else {}
        missing = [i for i in ocr if i not in scored]
        if missing:
            for r in self.store.get(missing, with_embeddings=True):
                assert r.embedding is not None
                scored[r.id] = float(np.dot(r.embedding, q))
        # best first; equal scores: the earlier memory first, however many candidates were fetched
        fused = sorted(
            ((s + OCR_WEIGHT * ocr.get(i, 0.0), i) for i, s in scored.items()), key=lambda p: (-p[0], p[1])
        )[:k]
        hits = self._hits([(i, s) for s, i in fused])
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
            try:
                (rec,) = self.store.get([int(memory_id)], with_embeddings=True)
            except KeyError:
                raise InputError(f"memory_id {memory_id}: no such memory") from None
            q = rec.embedding
            assert q is not None
        else:
            assert image is not None
            img = read_image(Path(image)) if isinstance(image, (str, os.PathLike)) else image
            q = self.embedder.embed_images([img])[0]
        skip = -1 if memory_id is None else int(memory_id)

        def ranked(n: int) -> list[Hit]:  # equal scores: the earlier memory first, as in text search
            scored = sorted(self.store.search_vector(q, n + 1, filt), key=lambda p: (-p[1], p[0]))
            return self._hits([(i, s) for i, s in scored if i != skip][:n])

        return diversity.top_hits(ranked, k, diverse, self.count())

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
            return self._grouped([Hit(memory=r) for r in self.store.by_time(t0, k, filt)])
        later = self.store.by_time(t0, k, filt)
        earlier = self._before(t0, k, filt)
        n_before = min(len(earlier), max(k // 2, k - len(later)))
        picked = earlier[len(earlier) - n_before :] + later[: k - n_before]
        return self._grouped([Hit(memory=r) for r in picked])

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
        x, y = _finite("x", x), _finite("y", y)
        z = None if z is None else _finite("z", z)
        if radius is not None and not _finite("radius", radius) > 0:
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

    def last_seen(
        self,
        query: str | None = None,
        *,
        image: np.ndarray | str | os.PathLike[str] | None = None,
        memory_id: int | None = None,
        vector: np.ndarray | None = None,
        after: TimeLike = None,
        before: TimeLike = None,
        near: Near | None = None,
        min_score: float | None = None,
        settings: ChangeSettings | None = None,
    ) -> Whereabouts:
        """Where a thing was seen, place by place (newest first), and whether each place still
        shows it: `still there`, `not revisited`, `moved` or `gone` (see `ravenmem.changes`).
        `before` is the "as of" time; `.now` is the place it is at now, if any. The thing is a
        `query` text, an `image`, a stored memory's picture (`memory_id`) or a query `vector`;
        `min_score` puts a floor under the match threshold."""
        from .changes import last_seen

        if query is not None:
            _check_text(query)
        img = read_image(Path(image)) if isinstance(image, (str, os.PathLike)) else image
        return last_seen(
            self,
            query,
            image=img,
            memory_id=memory_id,
            vector=vector,
            after=after,
            before=before,
            near=near,
            min_score=min_score,
            settings=settings,
        )

    def query(self) -> Query:
        from .query import Query

        return Query(self)

    def get(self, ids: Sequence[int]) -> list[MemoryRecord]:
        return self.store.get(list(ids))

    def all_records(self) -> list[MemoryRecord]:
        """Every memory in chronological order (no embeddings)."""
        if self.count() == 0:
            return []
        t0, _ = self.time_span()
        return self.store.by_time(t0, self.count())

    def image_file(self, rec: MemoryRecord) -> Path | None:
        """The file holding a record's picture, or None: no picture, a missing file, or a path
        that would leave the memory folder (`..`, a symlink leading out, an absolute path).
        Absolute paths (the original frames of a `thumb_size=0` memory) are followed only
        when the memory was opened with `external_images=True`."""
        if not rec.image_path or not isinstance(rec.image_path, str):
            return None
        if Path(rec.image_path).is_absolute():
            f: Path | None = Path(rec.image_path) if self.external_images else None
        else:
            f = confine(self.path, rec.image_path)
        try:
            return f if f is not None and f.is_file() else None
        except OSError:
            return None

    def load_image(self, rec: MemoryRecord) -> np.ndarray | None:
        """A record's picture as RGB uint8, or None when `image_file` gives none or the file
        does not decode as an image (logged)."""
        p = self.image_file(rec)
        if p is None:
            return None
        try:
            return read_image(p)
        except InputError as e:
            log.warning("memory %s: %s", rec.id, e)
            return None

    def info(self) -> dict[str, Any]:
        """What `ravenmem info` prints: counts, span, extent, embedder, bytes per memory, compression."""
        st = dict(self.store.stats())
        n = int(st.get("count") or 0)  # type: ignore[call-overload]
        thumbs = self.path / "thumbs"
        thumb_bytes = sum(p.stat().st_size for p in thumbs.glob("*.jpg")) if thumbs.exists() else 0
        store_bytes = int(st.get("bytes") or 0)  # type: ignore[call-overload]
        ingests = self.manifest.ingests
        seen, raw = _recording_totals(ingests)
        out: dict[str, Any] = {
            "path": str(self.path),
            "name": self.name,
            "embedder": self.manifest.embedder,
            "dim": self.dim,
            "store": self.manifest.store,
            "ocr": self.ocr_enabled,
            "thumb_size": self.thumb_size,
            "memories": n,
            "frames_seen": seen,
            "keyframe_ratio": (seen / n) if n and seen else None,
            "store_bytes": store_bytes,
            "thumb_bytes": thumb_bytes,
            "bytes_per_memory": (store_bytes / n) if n else None,
            "bytes_per_memory_with_thumbs": ((store_bytes + thumb_bytes) / n) if n else None,
            "raw_video_bytes": raw,
            "compression_vs_raw": (raw / store_bytes) if raw and store_bytes else None,
            "compression_vs_raw_with_thumbs": (raw / (store_bytes + thumb_bytes))
            if raw and store_bytes
            else None,
        }
        for key in ("t_min", "t_max"):
            if key in st:
                out[key] = st[key]
        bounds = [st.get(f"{c}_{m}") for c in "xyz" for m in ("min", "max")]
        if n and all(isinstance(b, (int, float)) for b in bounds):
            xyz = [float(b) for b in bounds]  # type: ignore[arg-type]
            out["extent"] = {c: [xyz[2 * i], xyz[2 * i + 1]] for i, c in enumerate("xyz")}
        if n:
            out["duration_s"] = float(st["t_max"]) - float(st["t_min"])  # type: ignore[arg-type]
        groups = self._groups.get(self.store)
        if groups and n:  # consolidated memories (additive keys: absent on a memory never consolidated)
            live = set(self.store.select().tolist())  # rows a killed forget left are not counted
            out["consolidated"] = sum(1 for i in groups if i in live)
            out["memories_represented"] = n + sum(g[0] - 1 for i, g in groups.items() if i in live)
            self._span = None
            out["t_min"], out["t_max"] = self.time_span()  # what the merged memories saw, too
            out["duration_s"] = out["t_max"] - out["t_min"]
        out["ingests"] = ingests
        return out

    # ---------------------------------------------------------------- lifecycle
    def close(self) -> None:
        try:
            if not self._closed:
                self._closed = True
                self._groups.close()
                self.store.close()
        finally:
            self._writer.release()

    @contextmanager
    def undo_create_on_error(self) -> Iterator[Memory]:
        """For a memory `create` made in this process: when the block fails before anything
        was stored, close it and remove exactly what `create` made (a failed first ingest
        leaves nothing behind). A memory that was opened, or holds memories, is kept."""
        try:
            yield self
        except BaseException:
            made = self._created
            if made is not None and not self._closed:
                try:
                    empty = self.store.count() == 0
                except Exception:  # the store itself failed: it holds nothing we stored
                    empty = True
                if empty:
                    try:
                        self.close()
                    finally:
                        made.undo()
            raise

    def __enter__(self) -> Memory:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def __repr__(self) -> str:
        return f"Memory({str(self.path)!r}, embedder={self.manifest.embedder!r}, memories={self.count()})"


def _validate_frame(f: Frame) -> None:
    img = f.image
    if not isinstance(img, np.ndarray) or img.ndim != 3 or img.shape[2] != 3 or img.dtype != np.uint8:
        shape = getattr(img, "shape", None)
        raise InputError(
            f"frame {f.source}#{f.index}: image must be an RGB uint8 array (H, W, 3), got {shape}"
        )
    if f.pose is None:
        raise InputError(f"frame {f.source}#{f.index}: no pose")
    if not np.isfinite(f.t):
        raise InputError(f"frame {f.source}#{f.index}: timestamp is not finite ({f.t})")


def _check_text(q: object) -> None:
    if not isinstance(q, str):
        raise InputError(f"a text query must be a string, got {type(q).__name__}")
    if not q.strip():
        raise InputError("empty text query")
    try:
        q.encode("utf-8")
    except UnicodeEncodeError:  # lone surrogates: a command-line argument with invalid UTF-8 bytes
        raise InputError(f"text query {q!r} is not valid UTF-8") from None


def _finite(name: str, v: object) -> float:
    """`v` as a finite float, or a one-line InputError naming the argument."""
    try:
        f = float(v)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number, got {v!r}") from None
    if not math.isfinite(f):
        raise InputError(f"{name} must be a finite number, got {v!r}")
    return f


def _recording_totals(ingests: list[dict[str, Any]]) -> tuple[int, int]:
    """Frames seen and raw decoded bytes over the ingest history, each recording counted once:
    running an ingest again (a resume, or the same recording appended twice) sees the same
    frames again, so runs with the same source identity count as their largest run. Runs
    without an identity (live adds) are all different and add up."""
    seen = raw = 0
    per_source: dict[str, tuple[int, int]] = {}
    for r in ingests:
        frames, size = _count(r.get("frames_seen")), _count(r.get("raw_bytes"))
        sid = r.get("source_id")
        if isinstance(sid, str) and sid:
            old = per_source.get(sid, (0, 0))
            per_source[sid] = (max(old[0], frames), max(old[1], size))
        else:
            seen, raw = seen + frames, raw + size
    return seen + sum(f for f, _ in per_source.values()), raw + sum(b for _, b in per_source.values())


def _count(v: object) -> int:
    """A count from the ingest history; anything that is not a finite number counts 0."""
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
        return 0
    return int(v)


def _check_embedder(emb: Embedder, manifest: Manifest, path: Path) -> None:
    if emb.name != manifest.embedder or emb.dim != manifest.dim:
        raise EmbedderMismatchError(
            f"memory {path} was built with embedder {manifest.embedder!r} (dim {manifest.dim}); "
            f"it cannot be searched with {emb.name!r} (dim {emb.dim})"
        )


def _resolve_embedder(embedder: str | Embedder) -> Embedder:
    return create_embedder(embedder) if isinstance(embedder, str) else embedder


class _Created:
    """What `create` made, so that a failure removes exactly that: the top folder it created
    (with everything below), or the entries it added to a folder that existed (and was empty)."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        top = folder
        while not top.parent.exists() and top.parent != top:
            top = top.parent
        self.top: Path | None = None if folder.exists() else top
        self.before = set(os.listdir(folder)) if folder.exists() else set()

    def undo(self) -> None:
        if self.top is not None:
            shutil.rmtree(self.top, ignore_errors=True)
            return
        if not self.folder.is_dir():
            return
        for name in set(os.listdir(self.folder)) - self.before:
            p = self.folder / name
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p, ignore_errors=True)
            else:
                p.unlink(missing_ok=True)


def _is_memory(p: Path) -> bool:
    try:
        return (p / MANIFEST).is_file()
    except OSError:
        return False


def create(
    path: str | os.PathLike[str],
    embedder: str | Embedder = "offline",
    store: str | None = None,
    thumb_size: int = 320,
    thumb_quality: int = 85,
    ocr: bool = True,
    exist_ok: bool = False,
    external_images: bool = False,
    wait: bool | float = False,
) -> Memory:
    """Create a new memory folder (or open it when `exist_ok` and it exists with the same embedder).

    The memory is returned holding its writer lock (`Memory.acquire_writer`; `wait` says
    whether to wait for another process writing or creating it).

    A memory is only created in a new or an empty folder: ravenmem never writes into a folder
    that holds something else. The embedder is resolved before anything is written, and if
    opening the store fails, what was created is removed again. `store`: None for the embedded
    store, `milvus:///PATH/INSIDE/THE/FOLDER/file.db` for Milvus Lite, `milvus://HOST:PORT`.
    """
    p = Path(path)
    if _is_memory(p):
        if not exist_ok:
            raise InputError(f"{p} already holds a memory; open it, or choose another folder")
        return open(p, embedder=embedder, external_images=external_images, writable=True, wait=wait)
    if p.exists():
        if not p.is_dir():
            raise InputError(f"{p} exists and is not a folder")
        if any(e.name != LOCK_FILE for e in p.iterdir()):  # the lock: another creator is at work
            raise InputError(
                f"{p} is a folder with other files and no {MANIFEST}: ravenmem creates a memory only "
                "in a new or empty folder (nothing was written)"
            )
    if isinstance(thumb_size, int) and not isinstance(thumb_size, bool) and thumb_size < 0:
        raise InputError(f"thumb_size must be >= 0 (0 = off), got {thumb_size}")
    uri = store_for_create(store, p)
    emb = _resolve_embedder(embedder)
    manifest = Manifest(
        embedder=emb.name,
        dim=emb.dim,  # may load the model: before anything is written
        store=uri,
        thumb_size=thumb_size,
        thumb_quality=thumb_quality,
        ocr=bool(ocr),
        created=time.time(),
    )
    made = _Created(p)
    writer = WriterLock(p)
    try:
        p.mkdir(parents=True, exist_ok=True)
        writer.acquire(wait)
    except MemoryBusyError:
        raise  # another process is creating it: what is there is not ours to remove
    except BaseException:
        made.undo()
        raise
    if _is_memory(p):  # the other process finished creating it while this one waited
        writer.release()
        if not exist_ok:
            raise InputError(f"{p} already holds a memory; open it, or choose another folder")
        return open(p, embedder=emb, external_images=external_images, writable=True, wait=wait)
    try:
        manifest.save(p)  # first: from here on the folder is recognisably a ravenmem memory
        st = open_store(manifest.store_uri(p), dim=manifest.dim)
    except BaseException:
        made.undo()
        writer.release()
        raise
    if store_kind(uri) == "remote":
        trust_store(uri)  # the user gave this server: opening the memory again is allowed
    mem = Memory(p, manifest, st, emb, external_images=external_images)
    mem._created = made
    mem._writer = writer
    return mem


def open(  # noqa: A001
    path: str | os.PathLike[str],
    embedder: str | Embedder | None = None,
    external_images: bool = False,
    writable: bool = False,
    wait: bool | float = False,
) -> Memory:
    """Open an existing memory folder.

    The manifest is checked before the store is touched (`ravenmem.manifest`). Passing an
    embedder other than the one it was built with is a clear error (its vectors would not be
    comparable); a spec such as `offline` is resolved to its full name before comparing.
    `external_images`: see `Memory`. `writable=True` takes the writer lock first (`wait` as in
    `Memory.acquire_writer`), so the store is read after any other writer finished; a Memory
    opened for reading can write too (its first write takes the lock and re-reads the store).
    """
    p = Path(path)
    if not writable or not _is_memory(p):
        return _open(p, embedder, external_images)
    writer = WriterLock(p)
    writer.acquire(wait)
    try:
        mem = _open(p, embedder, external_images)
    except BaseException:
        writer.release()
        raise
    try:
        mem._adopt_writer(writer)
    except BaseException:
        mem.close()
        raise
    return mem


def _open(p: Path, embedder: str | Embedder | None, external_images: bool) -> Memory:
    if not _is_memory(p):
        what = "does not exist" if not p.exists() else "is not a ravenmem memory (no memory.json)"
        raise InputError(f"memory {p} {what}")
    manifest = Manifest.load(p)
    if store_kind(manifest.store) == "remote":
        check_trusted(manifest.store)  # before any connection is made
    emb = None
    if embedder is not None:
        emb = _resolve_embedder(embedder)
        _check_embedder(emb, manifest, p)
    st = open_store(manifest.store_uri(p), dim=manifest.dim)
    return Memory(p, manifest, st, emb, external_images=external_images)
