"""Making a memory folder and opening one: `ravenmem.create` and `ravenmem.open`.

A memory is only created in a new or an empty folder (ravenmem never writes into a folder that
holds something else), and what a failed create made is removed again. Opening checks the
manifest before the store is touched (`ravenmem.memory.manifest`) and refuses an embedder other
than the one the memory was built with.
"""

from __future__ import annotations

import os
import time
from pathlib import Path

from ..embed.base import Embedder
from ..errors import InputError, MemoryBusyError
from ..store.base import open_store
from .core import check_store_present, read_folder, resolve_embedder, take_writer
from .facade import Memory
from .folder import LOCK, MANIFEST, Created, is_memory
from .lock import WriterLock
from .manifest import Manifest, store_for_create, store_kind, trust_store

__all__ = ["create", "open"]


def check_folder_name(p: Path) -> Path:
    """Refuse, before anything is created, a memory path SQLite cannot open (a name that is not
    UTF-8) or that cannot become a folder (a symbolic link that leads nowhere, or in a loop)."""
    try:
        str(p).encode("utf-8")
    except UnicodeEncodeError:
        shown = str(p).encode("utf-8", "backslashreplace").decode("ascii", "backslashreplace")
        raise InputError(
            f"{shown}: a memory folder's path must be valid UTF-8 (SQLite cannot open it)"
        ) from None
    if p.is_symlink() and not p.exists():
        raise InputError(f"{p}: a symbolic link that leads nowhere (or round in a loop); give a folder")
    return p


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
    p = check_folder_name(Path(path))
    if is_memory(p):
        if not exist_ok:
            raise InputError(f"{p} already holds a memory; open it, or choose another folder")
        return open(p, embedder=embedder, external_images=external_images, writable=True, wait=wait)
    if p.exists():
        if not p.is_dir():
            raise InputError(f"{p} exists and is not a folder")
        if any(e.name != LOCK for e in p.iterdir()):  # the lock: another creator is at work
            raise InputError(
                f"{p} is a folder with other files and no {MANIFEST}: ravenmem creates a memory only "
                "in a new or empty folder (nothing was written)"
            )
    if isinstance(thumb_size, int) and not isinstance(thumb_size, bool) and thumb_size < 0:
        raise InputError(f"thumb_size must be >= 0 (0 = off), got {thumb_size}")
    uri = store_for_create(store, p)
    emb = resolve_embedder(embedder)
    manifest = Manifest(
        embedder=emb.name,
        dim=emb.dim,  # may load the model: before anything is written
        store=uri,
        thumb_size=thumb_size,
        thumb_quality=thumb_quality,
        ocr=bool(ocr),
        created=time.time(),
    )
    made = Created(p)
    writer = WriterLock(p)
    try:
        p.mkdir(parents=True, exist_ok=True)
        writer.acquire(wait)
    except MemoryBusyError:
        raise  # another process is creating it: what is there is not ours to remove
    except BaseException:
        made.undo()
        raise
    if is_memory(p):  # the other process finished creating it while this one waited
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
    return Memory(p, manifest, st, emb, external_images=external_images, lock=writer, created=made)


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
    p = check_folder_name(Path(path))
    if not writable or not is_memory(p):
        return Memory(p, *read_folder(p, embedder), external_images=external_images)
    check_store_present(p, Manifest.load(p))  # before the lock file is touched
    lock = take_writer(p, wait)
    try:
        mem = Memory(p, *read_folder(p, embedder, writable=True), external_images=external_images, lock=lock)
    except BaseException:
        lock.release()
        raise
    try:
        mem.recover_writes()
    except BaseException:
        mem.close()
        raise
    return mem
