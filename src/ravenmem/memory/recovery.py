"""Clean-up after a killed writer: thumbnails whose memory was never stored, temporary files.

A batch's thumbnails are written before its records are committed (a record must never point at
a missing file), so a writer killed in between leaves thumbnails nothing refers to. Before
writing them, the writer lists them in a journal (`pending-thumbs-<id>.json` in the memory
folder) and deletes the journal once the store has committed the batch. The next writer (`Memory.acquire_writer`) reads
any journal left behind and deletes the listed thumbnails the store does not reference: it asks
the store for the memories of the journal's (source, frame index, time) and compares their
image paths. A store batch is one transaction, so it holds all of them or none.

Only files ravenmem names itself are ever removed: thumbnails named as `folder.thumb_name` names them
and listed in a journal, and `ravenmem.fsio` temporary files that no live process holds.
"""

from __future__ import annotations

import json
import logging
import os
import uuid
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from ..fsio import atomic_write_json, move, read_text, remove_stale_temp_files
from ..store.base import Store
from .folder import (
    JOURNAL_NAME,
    JOURNAL_PREFIX,
    MANIFEST,
    TEXT_JOURNAL_PREFIX,
    THUMBS,
    aside_name,
    journal_name,
    thumb_file,
)

log = logging.getLogger(__name__)

_WRITER_ONLY = (f"{MANIFEST}.", JOURNAL_PREFIX, TEXT_JOURNAL_PREFIX)  # files only the lock holder writes

MAX_JOURNAL = 256 << 20  # bytes: a forget of a million memories lists ~80 MB

# (thumbnail path relative to the memory folder, source, frame index, time)
Entry = tuple[str, str, int, float]


def stored_ids(store: Store, entries: Sequence[tuple[str, int, float]]) -> dict[tuple[str, int, float], int]:
    """The ids of the memories the store holds for (source, frame index, time) entries: how a
    journal written before its batch committed finds what the batch stored."""
    out: dict[tuple[str, int, float], int] = {}
    for source in {e[0] for e in entries}:
        sf = store.source_frames(source)
        want = {(i, t) for s, i, t in entries if s == source}
        near = np.flatnonzero(np.isin(sf.frame_index, [i for i, _ in want]))
        for k in near:
            key = (int(sf.frame_index[k]), float(sf.t[k]))
            if key in want:
                out[(source, *key)] = int(sf.ids[k])
    return out


def begin(folder: Path, entries: Sequence[Entry]) -> Path:
    """Write (durably) the journal of thumbnails about to be written; returns its path."""
    path = folder / journal_name(uuid.uuid4().hex[:12])
    atomic_write_json(path, {"thumbs": [list(e) for e in entries]})
    return path


def end(journal: Path) -> None:
    """The batch is committed: its journal goes (if this unlink is lost in a crash, recovery
    finds every thumbnail referenced and only deletes the journal)."""
    journal.unlink(missing_ok=True)


def settle(folder: Path, store: Store, journal: Path) -> int:
    """Delete the journal's thumbnails that no stored memory references, then the journal.

    It never fails (so that a journal can never keep a memory from opening): a journal it cannot
    read, or an entry it cannot act on (a name the file system refuses, a source the store
    refuses), is logged and the journal moved aside (`folder.aside_name`) with whatever it could
    not settle; the thumbnails it could settle are."""
    try:
        raw = json.loads(read_text(journal, limit=MAX_JOURNAL, what="thumbnail journal"))["thumbs"]
        entries = [(str(n), str(s), int(i), float(t)) for n, s, i, t in raw]
    except Exception as e:  # anything at all: the memory must open
        return set_aside(journal, f"unreadable ({e})")
    failed: list[str] = []
    referenced: set[str] = set()
    for source in {e[1] for e in entries}:
        try:
            found = stored_ids(store, [(s, i, t) for _, s, i, t in entries if s == source])
            if found:
                referenced.update(r.image_path or "" for r in store.get(sorted(found.values())))
        except Exception as e:  # the store cannot say: keep this source's thumbnails
            failed.append(f"source {source[:80]!r}: {e}")
            referenced.update(n for n, s, _, _ in entries if s == source)
    removed = 0
    for name, *_ in entries:
        try:
            p = thumb_file(folder, name)
            if name in referenced or p is None:
                continue
            if p.is_file():
                p.unlink()
                removed += 1
        except OSError as e:  # e.g. a name too long for the file system (ENAMETOOLONG)
            failed.append(f"thumbnail {name[:80]!r}: {e.strerror or e}")
    if failed:
        set_aside(journal, "; ".join(failed[:3]))
    else:
        end(journal)
    return removed


def set_aside(journal: Path, why: str, what: str = "thumbnail journal") -> int:
    """Log a journal recovery cannot act on and move it out of recovery's way; 0 removed."""
    target = journal.with_name(aside_name(journal.name))
    try:
        move(journal, target)
        log.warning("%s: %s set aside as %s: %s", journal, what, target.name, why)
    except OSError as e:
        log.warning("%s: %s left as is (%s; cannot move it: %s)", journal, what, why, e)
    return 0


def recover(folder: Path, store: Store) -> dict[str, int]:
    """What a new writer cleans before writing: journals left by a killed writer (and the
    thumbnails they list that were never stored), stale temporary files. Returns the counts.

    Only the memory folder itself is listed on every call; `thumbs/` (a million files in a big
    memory) only after a crash, i.e. when a journal was left: a thumbnail's temporary file can
    only exist while its batch's journal does. The caller holds the writer lock, so no other
    process is writing a thumbnail, a journal or the manifest: their temporary files are removed
    whatever their age (a writer killed less than a second ago leaves one too, and the same
    command run again at once must not keep it). Other temporary files (caches that readers
    write too: the store's index and columns) are left alone while younger than
    `remove_stale_temp_files`' margin, so they are waited for (at most 2 s, only when there is
    such a file) and removed then if nobody holds them: a writer restarted right after a kill -9
    in the middle of a cache save would otherwise keep its temporary file.
    """
    journals = [e for e in sorted(os.listdir(folder)) if JOURNAL_NAME.fullmatch(e)]
    removed = sum(settle(folder, store, folder / j) for j in journals)  # never raises
    temps = [p for t in _WRITER_ONLY for p in remove_stale_temp_files(folder, min_age=0.0, target=t)]
    temps += remove_stale_temp_files(folder, wait=True)
    if journals:
        temps += remove_stale_temp_files(folder / THUMBS, min_age=0.0)
    if removed or temps:
        log.info(
            "%s: removed %d unreferenced thumbnail(s), %d temporary file(s)", folder, removed, len(temps)
        )
    return {"thumbnails": removed, "temp_files": len(temps)}
