"""Text read after the write: a memory searchable by picture at once, by its words when OCR lands.

OCR costs about as much as embedding a frame. A live robot waits for the answer to each frame
(the ack), and a recorded ingest waits for each batch, so `Memory.add_frames(..., text="later")`
stores the frames with their embeddings first and reads their text in a background thread
(`LateText`), which writes it into the store when it is read (`TextStore.set_ocr_text`).

Nothing is lost in a crash: before the frames are stored, the full-size pictures whose text is
still to be read are written (durably) to a journal in the memory folder
(`pending-text-<id>.npz`, named by `memory.folder`); the journal goes once their text is
stored. The next writer (`Memory.acquire_writer`, through `recovery`) reads the text of every
journalled frame the store holds and has no text for yet, then deletes the journal; frames the
store never took are dropped with it.

The thread runs at a lower priority than the process (`ravenmem.threads.TEXT_NICE`, inherited by
the OCR engine's threads, which it creates), so that searches are answered first; its queue
is bounded (`MAX_BATCHES`), so that adds wait rather than let unread pictures pile up in memory.
"""

from __future__ import annotations

import json
import logging
import os
import queue
import threading
import uuid
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np

from ..fsio import atomic_open
from ..store.base import Store, TextStore
from ..threads import TEXT_NICE, lower_priority
from ..types import Frame
from .folder import TEXT_JOURNAL_NAME, text_journal_name
from .recovery import set_aside, stored_ids

log = logging.getLogger(__name__)

MAX_BATCHES = 8  # batches whose text is waiting to be read
TEXT_THREADS = 1  # the OCR engine's threads when text is read after the write (one core)

Reader = Callable[[np.ndarray], str]
Entry = tuple[str, int, float]  # (source, frame index, time): how the store finds a frame


def begin(folder: Path, frames: Sequence[Frame]) -> Path:
    """Write (durably) the pictures of `frames`, whose text is read after they are stored."""
    path = folder / text_journal_name(uuid.uuid4().hex[:12])
    entries = [[f.source, int(f.index), float(f.t)] for f in frames]
    arrays = {f"image{i}": np.ascontiguousarray(f.image) for i, f in enumerate(frames)}
    with atomic_open(path) as fh:
        np.savez(fh, entries=np.array(json.dumps(entries)), **arrays)  # type: ignore[arg-type]
    return path


def end(journal: Path) -> None:
    """The journal's text is stored (or its frames were never): it goes."""
    journal.unlink(missing_ok=True)


def read(journal: Path) -> tuple[list[Entry], list[np.ndarray]]:
    """The entries and pictures of a journal."""
    with np.load(journal, allow_pickle=False) as z:
        raw = json.loads(str(z["entries"]))
        entries = [(str(s), int(i), float(t)) for s, i, t in raw]
        return entries, [z[f"image{k}"] for k in range(len(entries))]


def recover(folder: Path, store: Store, reader: Callable[[], Reader]) -> int:
    """Read the text of the frames that journals left by a killed writer list and the store
    holds without text; returns how many got their text. `reader` makes the OCR reader (only
    called when there is a journal). It never fails (a journal must not keep a memory from
    opening): a journal it cannot act on is logged and set aside (`recovery.set_aside`)."""
    journals = [folder / e for e in sorted(os.listdir(folder)) if TEXT_JOURNAL_NAME.fullmatch(e)]
    done = 0
    ocr: Reader | None = None
    for journal in journals:
        try:
            entries, images = read(journal)
            found = stored_ids(store, entries)
            ids, todo = [], []
            for entry, image in zip(entries, images, strict=True):
                i = found.get(entry)
                if i is not None and not store.get([i])[0].ocr_text:
                    ids.append(i)
                    todo.append(image)
            if ids and isinstance(store, TextStore):
                ocr = ocr or reader()
                done += store.set_ocr_text(ids, [ocr(im) for im in todo])
        except Exception as e:  # anything at all: the memory must open
            set_aside(journal, str(e), "text journal")
            continue
        end(journal)
    if journals:
        log.info("%s: read the text of %d frame(s) a killed writer left unread", folder, done)
    return done


class LateText:
    """The background reader of one open memory (see the module docstring).

    `reader()` makes the OCR reader, in the thread (so that its engine's threads share the
    thread's priority); `write(journal, ids, texts)` stores the text and drops the journal (the
    memory's writer handle, `Writer.text_read`). `submit` blocks while `MAX_BATCHES` batches
    wait.
    """

    def __init__(
        self, reader: Callable[[], Reader], write: Callable[[Path, list[int], list[str]], None]
    ) -> None:
        self._make_reader = reader
        self._write = write
        self._queue: queue.Queue[tuple[Path, list[int], list[np.ndarray]] | None] = queue.Queue(MAX_BATCHES)
        self._thread: threading.Thread | None = None
        self._lock = threading.Lock()
        self._idle = threading.Condition(self._lock)
        self._pending = 0
        self.read = 0

    def submit(self, journal: Path, ids: list[int], images: list[np.ndarray]) -> None:
        """Read the text of stored memories `ids` (their pictures `images`, kept in `journal`)."""
        with self._lock:
            if self._thread is None:
                self._thread = threading.Thread(target=self._run, name="ravenmem-ocr", daemon=True)
                self._thread.start()
            self._pending += 1
        self._queue.put((journal, ids, images))

    def wait(self, timeout: float | None = None) -> bool:
        """Block until every submitted batch's text is stored; False on timeout."""
        with self._idle:
            return self._idle.wait_for(lambda: self._pending == 0, timeout)

    @property
    def pending(self) -> int:
        """Batches whose text is not stored yet."""
        return self._pending

    def close(self, timeout: float | None = None) -> None:
        """Read what was submitted, then stop the thread."""
        with self._lock:
            thread, self._thread = self._thread, None
        if thread is not None:
            self._queue.put(None)
            thread.join(timeout)

    def _run(self) -> None:
        lower_priority(TEXT_NICE)
        ocr: Reader | None = None
        while True:
            job = self._queue.get()
            if job is None:
                return
            journal, ids, images = job
            try:
                ocr = ocr or self._make_reader()
                self._write(journal, ids, [ocr(im) for im in images])
                self.read += len(ids)
            except Exception:  # the journal stays: the next writer reads this text
                log.exception("reading the text of %d memories failed", len(ids))
            finally:
                with self._idle:
                    self._pending -= 1
                    self._idle.notify_all()
