"""The `Memory` facade: one folder on disk that holds what a robot saw, where and when.

A memory folder holds the manifest, the store's files, thumbnails and the sidecars that
`ravenmem.memory.folder` names. The facade turns user queries into vectors, fuses the OCR
channel, resolves time expressions and hands out `Hit`s; the store does the indexing. It is
put together from one module per concern, each a class over `Core` (the state and the shared
reads): the searches (`search`), where a thing is now (`changes`), forgetting and consolidation
(`lifelong`), `info`, the map the poses are in (`anchor`); this module adds the writes and the lifecycle. `ravenmem.create` and
`ravenmem.open` (`memory.create`) make one.

Nothing read from a memory reaches outside its folder: the manifest is checked before the store
is opened, the store must live in the folder (or be the server the user named at create time),
and a record's image path is only followed when it stays inside the folder.
"""

from __future__ import annotations

import uuid
from collections.abc import Iterable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import InputError
from ..fsio import reports_full_disk
from ..imageio import write_jpeg
from ..store.base import TextStore
from ..types import Frame, MemoryRecord, Pose
from .anchor import Anchoring
from .changes import Changes
from .core import ocr_reader
from .folder import thumb_name
from .info import Info
from .lifelong.consolidate import Consolidation
from .lifelong.forget import Forgetting
from .protocol import MemoryLike
from .query import Query
from .search import Search
from .text import LateText

__all__ = ["Memory"]


class Memory(Search, Changes, Forgetting, Consolidation, Info, Anchoring, MemoryLike):
    """A visual memory: add frames, then search by text, image, time or position.

    Use `ravenmem.create(path)` for a new memory and `ravenmem.open(path)` for an existing one.
    The embedder is loaded on first use, so time and position queries start instantly.
    `external_images=True` lets `image_file`/`load_image` follow absolute image paths (memories
    built with `thumb_size=0` store the original frames' paths); off by default, because a
    memory folder from elsewhere could name any file on this machine.

    It declares `MemoryLike` (what the rest of ravenmem may rely on), so the type checker holds
    the searches' signatures to the protocol's.
    """

    # ---------------------------------------------------------------- writing
    def add(self, image: np.ndarray, pose: Pose, t: float, source: str = "live", frame_index: int = 0) -> int:
        """Append one observation (thread-safe; another thread may search meanwhile)."""
        return self.add_frames([Frame(image=image, t=t, pose=pose, source=source, index=frame_index)])[0]

    @reports_full_disk
    def add_frames(
        self, frames: Sequence[Frame], embeddings: np.ndarray | None = None, text: str = "now"
    ) -> list[int]:
        """Embed, OCR, thumbnail and store frames; durable when this returns.

        `embeddings` may be passed when the caller already computed them (the ingest pipeline
        does, for novelty filtering), so that frames are never embedded twice. The first write
        takes the writer lock (`acquire_writer`) without waiting. `text="later"` (on a memory
        with OCR whose store can change text, `TextStore`) stores the frames before their text
        is read, which a background thread then does (`ravenmem.memory.text`: searchable by
        picture now, by their words when the text lands; `wait_text` waits for it; journalled,
        so a crash loses neither).
        """
        if text not in ("now", "later"):
            raise InputError(f"text must be 'now' or 'later', got {text!r}")
        if not frames:
            return []
        for f in frames:
            f.check()  # the ranges of ravenmem.types, before anything is written
        writer = self.writer()
        later = text == "later" and self.ocr_enabled and isinstance(self.store, TextStore)
        if embeddings is None:
            embeddings = self.embedder.embed_images([f.image for f in frames])
        embeddings = np.asarray(embeddings, dtype=np.float32)
        if embeddings.shape != (len(frames), self.dim):
            raise InputError(
                f"embeddings have shape {embeddings.shape}, expected ({len(frames)}, {self.dim})"
            )
        read_now = self.ocr_enabled and not later
        texts = [self._read_text(f.image) for f in frames] if read_now else [""] * len(frames)
        paths = [self._thumb_name(f) for f in frames]
        pending = writer.text_journal(frames) if later else None
        # thumbnails go to disk before their records commit; the journal lets the next writer
        # delete them if this process dies in between (ravenmem.memory.recovery)
        journal = None
        if self.thumb_size > 0:
            journal = writer.journal(
                [(p or "", f.source, int(f.index), float(f.t)) for p, f in zip(paths, frames)]
            )
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
            with writer.change():
                ids = self.store.add(records, embeddings)
        except BaseException:
            if journal is not None:  # delete what the store did not take (it may have: check)
                writer.settle(self.store, journal)
            if pending is not None:
                writer.text_failed(self.store, pending)
            raise
        if journal is not None:
            writer.end(journal)
        if pending is not None:
            self._late_text().submit(pending, ids, [f.image for f in frames])
        return ids

    def wait_text(self, timeout: float | None = None) -> bool:
        """Wait until the text of every frame added with `text="later"` is stored (True), or
        `timeout` seconds passed (False)."""
        return self._late is None or self._late.wait(timeout)

    def _late_text(self) -> LateText:
        with self._lock:
            if self._late is None:
                store = self.store
                assert isinstance(store, TextStore)
                self._late = LateText(
                    ocr_reader,
                    lambda journal, ids, texts: self.writer().text_read(store, journal, ids, texts),
                )
            return self._late

    @reports_full_disk
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
        writer = self.writer()

        def checked() -> Iterator[tuple[Sequence[MemoryRecord], np.ndarray]]:
            for records, emb in batches:
                if np.ndim(emb) != 2 or np.shape(emb)[1] != self.dim:
                    raise InputError(
                        f"embeddings have shape {np.shape(emb)}, expected (N, {self.dim}) for this memory's embedder"
                    )
                yield records, emb

        try:  # not under the memory's lock: searches go on during a long import
            return self.store.add_many(checked(), resume=resume)
        finally:
            writer.changed()

    def _read_text(self, image: np.ndarray) -> str:
        if self._ocr is None:
            self._ocr = ocr_reader(threads=None)
        return str(self._ocr(image))

    def _thumb_name(self, f: Frame) -> str | None:
        """The thumbnail's path relative to the folder (None when thumbnails are off)."""
        if self.thumb_size <= 0:
            return None
        return thumb_name(f.t, uuid.uuid4().hex[:8])

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

    @reports_full_disk
    def record_ingest(self, report: dict[str, Any]) -> None:
        """Append an ingest run's counts to the manifest (frames seen/kept, raw bytes)."""
        with self.writer().change():
            self.manifest.ingests.append(report)
            self.manifest.save(self.path)

    def query(self) -> Query:
        """A fluent query over this memory (`ravenmem.memory.query`)."""
        return Query(self)

    # ---------------------------------------------------------------- lifecycle
    def close(self) -> None:
        try:
            if not self._closed:
                if self._late is not None:  # the text read after the write is stored first
                    self._late.close()
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
