"""The writer handle: what every write to a memory folder goes through.

A memory has one writer at a time (`lock`). Its writes touch four things that must stay in
step: the store, the thumbnails in the folder (listed in a journal while they are written or
deleted, `recovery`), the pictures whose text is read after they are stored (a journal until
their text is, `text`) and the sidecar table of consolidated groups (`groups`). The
handle holds the lock, writes and settles the journals, opens the sidecar table, and tells the
open memory's read caches (its time span, its view of the groups) that a write changed them.
Adding frames, `forget`, `consolidate` and the ingest history use it (`Memory.writer()`);
nothing else reaches into a memory's state to write.
"""

from __future__ import annotations

import threading
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from pathlib import Path

import numpy as np

from ..store.base import Store, TextStore
from ..types import Frame
from . import recovery, text
from .groups import GroupTable, drop_rows, recover_groups
from .lock import WriterLock


class Writer:
    """The writer's handle on one memory folder (see the module docstring)."""

    def __init__(
        self,
        folder: Path,
        mutex: threading.RLock,
        changed: Callable[[bool], None],
        lock: WriterLock | None = None,
        reader: Callable[[], text.Reader] | None = None,
    ) -> None:
        self.folder = folder
        self._mutex = mutex  # the open memory's lock: a search never sees half a change
        self._changed = changed
        self._lock = lock or WriterLock(folder)
        self._reader = reader  # makes the OCR reader that recovery reads journalled text with

    @property
    def held(self) -> bool:
        return self._lock.held

    def hold(self, lock: WriterLock) -> None:
        """Hold `lock` (acquired before the memory read its store)."""
        self._lock = lock

    def recover(self, store: Store) -> None:
        """Clean up after a writer that was killed (journals, temporary files, half-done
        sidecar batches); the lock is given up when that fails."""
        try:
            recovery.recover(self.folder, store)
            recover_groups(self.folder, store)
            if self._reader is not None and isinstance(store, TextStore):
                with self.change():
                    text.recover(self.folder, store, self._reader)
        except BaseException:
            self._lock.release()
            raise

    def release(self) -> None:
        self._lock.release()

    @contextmanager
    def change(self, groups: bool = False) -> Iterator[None]:
        """Around a store write: searches wait for it, and the caches it changes are dropped
        (with `groups`: the consolidated groups too)."""
        with self._mutex:
            try:
                yield
            finally:
                self._changed(groups)

    def changed(self, groups: bool = False) -> None:
        """A store write made without holding the memory's lock (a long bulk import) is done."""
        self._changed(groups)

    # ---------------------------------------------------------------- thumbnails
    def journal(self, entries: Sequence[recovery.Entry]) -> Path | None:
        """List thumbnails about to be written or deleted (durably); None when there are none."""
        return recovery.begin(self.folder, entries) if entries else None

    def settle(self, store: Store, journal: Path) -> int:
        """Delete the journal's thumbnails that no stored memory references; how many went."""
        return recovery.settle(self.folder, store, journal)

    def end(self, journal: Path) -> None:
        """The batch is committed and every thumbnail it lists is referenced: the journal goes."""
        recovery.end(journal)

    # ---------------------------------------------------------------- text read after the write
    def text_journal(self, frames: Sequence[Frame]) -> Path:
        """Keep (durably) the pictures of frames about to be stored whose text is read after."""
        return text.begin(self.folder, frames)

    def text_read(self, store: TextStore, journal: Path, ids: list[int], texts: list[str]) -> None:
        """The journal's text was read: store it (searches see it at once), then drop the journal."""
        with self.change():
            store.set_ocr_text(ids, texts)
        text.end(journal)

    def text_failed(self, store: Store, journal: Path) -> None:
        """Storing the journal's batch failed: the journal goes, unless the store took its
        frames after all (the next writer then reads their text)."""
        entries, _ = text.read(journal)
        if not recovery.stored_ids(store, entries):
            text.end(journal)

    # ---------------------------------------------------------------- sidecars
    def group_table(self) -> GroupTable:
        """The sidecar table of consolidated groups, for writing (close it after use)."""
        return GroupTable(self.folder)

    def deleted(self, ids: np.ndarray, groups: bool = True) -> None:
        """The store deleted `ids`: their sidecar rows go (`groups=False`: the caller settled
        the groups table itself)."""
        if groups:
            drop_rows(self.folder, ids)
        self.changed(groups=True)
