"""The state a `Memory` is built on, and the reads every part of it shares.

`Core` holds what one open memory is made of (its folder, manifest, store, embedder, the writer
handle and the readers' caches) and answers the questions every search, `last_seen`, `forget`
and `consolidate` asks: how many memories, which time span, which records, which filter. The
facade (`ravenmem.memory.facade.Memory`) is this plus the searches, the sightings, the
lifelong operations and the writes, each in its own module over this one.
"""

from __future__ import annotations

import errno
import logging
import math
import os
import threading
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..embed.base import Embedder, create_embedder
from ..errors import EmbedderMismatchError, EmptyMemoryError, InputError, MemoryNotFoundError, NotFoundError
from ..imageio import read_image
from ..store.base import Store, open_store
from ..store.presence import check_present
from ..timeparse import TimeContext, parse_time
from ..types import Filter, Hit, MemoryRecord, Region, check_id
from . import text
from .folder import MANIFEST, Created, has_thumbs, is_memory
from .groups import Group, GroupView, annotate
from .lock import WriterLock
from .manifest import Manifest, check_trusted, confine, store_kind
from .protocol import Near, TimeLike
from .text import LateText, Reader
from .writer import Writer

log = logging.getLogger(__name__)


class Core:
    """One open memory folder: its parts, the shared reads, and the writer handle."""

    def __init__(
        self,
        path: Path,
        manifest: Manifest,
        store: Store,
        embedder: Embedder | None,
        external_images: bool = False,
        lock: WriterLock | None = None,
        created: Created | None = None,
    ) -> None:
        self.path = path
        self.manifest = manifest
        self.store = store
        self.external_images = external_images
        self._embedder = embedder
        self._lock = threading.RLock()
        self._span: tuple[float, float] | None = None
        self.writes = 0  # how many store writes this object made (caches of whole-memory facts)
        self._closed = False
        self._groups = GroupView(path)  # consolidated memories: count and span (memory.lifelong)
        self._writer = Writer(path, self._lock, self._changed, lock, reader=ocr_reader)
        self._created = created  # what `create` made in this process (`undo_create_on_error`)
        self._ocr: Reader | None = None  # reads text before the write, made at the first frame
        self._late: LateText | None = None  # reads text after the write (`add_frames(text="later")`)

    # ---------------------------------------------------------------- parts
    @property
    def embedder(self) -> Embedder:
        with self._lock:
            if self._embedder is None:
                self._embedder = create_embedder(self.manifest.embedder)
                check_embedder(self._embedder, self.manifest, self.path)
            return self._embedder

    @property
    def ocr_enabled(self) -> bool:
        return self.manifest.ocr

    @property
    def thumb_size(self) -> int:
        return self.manifest.thumb_size

    @property
    def dim(self) -> int:
        return self.manifest.dim

    @property
    def name(self) -> str:
        """The display name the user gave this memory (`set_name`), else the folder's name."""
        return self.manifest.name or self.path.name

    def writer(self) -> Writer:
        """The writer handle, holding the writer lock: taken now (without waiting) when this
        Memory does not hold it yet (see `acquire_writer`)."""
        if not self._writer.held:
            self.acquire_writer(wait=False)
        return self._writer

    def acquire_writer(self, wait: bool | float = False) -> None:
        """Become the one writer of this memory folder (see `ravenmem.memory.lock`), and clean
        up after a writer that was killed (`ravenmem.memory.recovery`: unreferenced
        thumbnails, temp files).

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
            check_store_present(self.path, self.manifest)  # before the lock file is touched
            lock = take_writer(self.path, wait)
            try:
                # what this Memory read at open may be stale: another writer may have added
                # memories (the store hands out ids from its own count) or ingest records since.
                # Closed first: Milvus Lite serves one client per file.
                self.store.close()
                self.manifest, self.store, _ = read_folder(self.path, None, writable=True)
                self._span = None
            except BaseException:
                lock.release()
                raise
            self._writer.hold(lock)
            self.recover_writes()

    def recover_writes(self) -> None:
        """The writer's clean-up after a writer that was killed: the journals and temporary
        files (`recovery`, `groups`), then a re-anchoring left half done (`anchor`). The lock is
        given up when that fails."""
        self._writer.recover(self.store)
        try:
            from .transform import finish

            self.manifest = finish(self.path, self.store, self.manifest) or self.manifest
        except BaseException:
            self._writer.release()
            raise

    def release_writer(self) -> None:
        """Let another process write (this Memory takes the lock again at its next write)."""
        with self._lock:
            self._writer.release()

    @property
    def is_writer(self) -> bool:
        return self._writer.held

    def _changed(self, groups: bool) -> None:
        """A write changed the store (and, with `groups`, the consolidated groups)."""
        self._span = None
        self.writes += 1
        if groups:
            self._groups.invalidate()

    # ---------------------------------------------------------------- shared reads
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
                for _, first, last in self.groups().values():  # what merged memories saw
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

    def _named_time(self, name: str, expr: TimeLike) -> float:
        try:
            return self.parse_time(expr)
        except InputError as e:
            raise InputError(f"{name}: {e}") from None

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
            try:
                region = Region(x, y, r)
            except InputError as e:
                raise InputError(f"near {list(near)!r}: {e}") from None
        return Filter(
            after=None if after is None else self._named_time("after", after),
            before=None if before is None else self._named_time("before", before),
            region=region,
        )

    def get(self, ids: Sequence[int]) -> list[MemoryRecord]:
        """The records of `ids`, in the order given; `NotFoundError` names the ids not stored."""
        ids = [check_id(i) for i in ids]  # 10**30 is a one-line error, not an OverflowError
        try:
            return self.store.get(list(ids))
        except KeyError:
            have = {r.id for r in self.stored(ids)}
            missing = [str(i) for i in ids if i not in have]
            raise NotFoundError(f"no such memory: {', '.join(missing[:10])}") from None

    def stored(self, ids: Sequence[int], with_embeddings: bool = False) -> list[MemoryRecord]:
        """The records of `ids` that are still stored, in the order given. A reader that opened
        the memory before another process ran `forget` or `consolidate` (a read-only service,
        `ravenmem mcp`) still has the removed memories in its index; they are skipped here
        rather than failing the search."""
        ids = [check_id(i) for i in ids]
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

    def embedded(self, memory_id: object) -> MemoryRecord:
        """One record with its embedding (a search "like memory N"); `NotFoundError` when it is
        not stored, a one-line `InputError` when `memory_id` is no id at all."""
        mid = check_id(memory_id, "memory_id")
        try:
            (rec,) = self.store.get([mid], with_embeddings=True)
        except KeyError:
            raise NotFoundError(f"memory_id {mid}: no such memory") from None
        assert rec.embedding is not None
        return rec

    def all_records(self) -> list[MemoryRecord]:
        """Every memory in chronological order (no embeddings)."""
        if self.count() == 0:
            return []
        t0, _ = self.time_span()
        return self.store.by_time(t0, self.count())

    def groups(self) -> dict[int, Group]:
        """Every memory that stands for several (consolidated): id -> (count, first_t, last_t)."""
        return self._groups.get(self.store)

    def group(self, memory_id: int) -> Group | None:
        """(count, first_t, last_t) when the memory stands for several (consolidated), else None."""
        return self.groups().get(int(memory_id))

    def grouped(self, hits: list[Hit]) -> list[Hit]:
        """`hits` with `count`/`span` set where a memory stands for several (consolidated)."""
        annotate(hits, self.groups())
        return hits

    # ---------------------------------------------------------------- pictures
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


def ocr_reader(threads: int | None = -1) -> Reader:
    """A new OCR reader as a memory reads frames with (its models load at the first picture);
    `threads` for onnxruntime (-1: `text.TEXT_THREADS`, for text read after the write; None:
    onnxruntime decides)."""
    from ..embed.ocr import OcrReader

    n = text.TEXT_THREADS if threads == -1 else threads
    return OcrReader(threads=n).read


def check_embedder(emb: Embedder, manifest: Manifest, path: Path) -> None:
    """The embedder a memory was built with, or a one-line error naming both."""
    if emb.name != manifest.embedder or emb.dim != manifest.dim:
        raise EmbedderMismatchError(
            f"memory {path} was built with embedder {manifest.embedder!r} (dim {manifest.dim}); "
            f"it cannot be searched with {emb.name!r} (dim {emb.dim})"
        )


def resolve_embedder(embedder: str | Embedder) -> Embedder:
    return create_embedder(embedder) if isinstance(embedder, str) else embedder


def read_folder(
    p: Path, embedder: str | Embedder | None, writable: bool = False
) -> tuple[Manifest, Store, Embedder | None]:
    """A memory folder's manifest (checked before anything else), its store, and the embedder
    asked for (checked against the manifest).

    Unless `writable`, the embedded store is opened read-only: a reader writes nothing in the
    folder. A store that is missing while the memory's thumbnails are there is refused
    (`store.local.check_present`) rather than created empty beside them."""
    if not is_memory(p):
        what = "does not exist" if not p.exists() else f"is not a ravenmem memory (no {MANIFEST})"
        raise MemoryNotFoundError(f"memory {p} {what}")
    manifest = Manifest.load(p)
    if store_kind(manifest.store) == "remote":
        check_trusted(manifest.store)  # before any connection is made
    emb = None
    if embedder is not None:
        emb = resolve_embedder(embedder)
        check_embedder(emb, manifest, p)
    check_store_present(p, manifest)
    opts = {"read_only": not writable} if store_kind(manifest.store) == "local" else {}
    return manifest, open_store(manifest.store_uri(p), dim=manifest.dim, **opts), emb


def take_writer(p: Path, wait: bool | float) -> WriterLock:
    """The writer lock of memory folder `p`, taken. A folder this process cannot write (read-only
    media, an archive, another user's memory) is a one-line error here, before any work: every
    reading command still answers there, since readers never take the lock."""
    lock = WriterLock(p)
    try:
        lock.acquire(wait)
    except OSError as e:
        if e.errno not in (errno.EROFS, errno.EACCES, errno.EPERM):
            raise
        raise InputError(
            f"{p}: cannot write in this memory folder ({os.strerror(e.errno)}); "
            "reading commands (info, search, ask) still work"
        ) from None
    return lock


def check_store_present(p: Path, manifest: Manifest) -> None:
    """Refuse (before anything is created or locked) a memory whose embedded store is missing or
    empty while its index, columns or thumbnails are there (`store.local.check_present`)."""
    if store_kind(manifest.store) == "local":
        check_present(p, has_thumbs(p))


def check_text(q: object) -> None:
    if not isinstance(q, str):
        raise InputError(f"a text query must be a string, got {type(q).__name__}")
    if not q.strip():
        raise InputError("empty text query")
    try:
        q.encode("utf-8")
    except UnicodeEncodeError:  # lone surrogates: a command-line argument with invalid UTF-8 bytes
        raise InputError(f"text query {q!r} is not valid UTF-8") from None


def finite(name: str, v: object) -> float:
    """`v` as a finite float, or a one-line InputError naming the argument."""
    try:
        f = float(v)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise InputError(f"{name} must be a number, got {v!r}") from None
    if not math.isfinite(f):
        raise InputError(f"{name} must be a finite number, got {v!r}")
    return f
