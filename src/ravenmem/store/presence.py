"""Whether the embedded store's files are there: `store.sqlite` (the truth) and its caches.

Its own module, without the store's heavy imports, because the memory asks it before it takes a
writer lock or opens anything (`ravenmem.memory.core.check_store_present`).
"""

from __future__ import annotations

from pathlib import Path

from ..errors import InputError

STORE_FILES = ("store.sqlite", "index.faiss", "columns.cache")


def check_present(folder: Path, must_exist: bool) -> None:
    """Refuse to open a store whose `store.sqlite` is missing or empty while its index or columns
    file is there, or (`must_exist`: a reader, or a memory with thumbnails) at all: creating it
    would give an empty store and rewrite the index without its vectors. Nothing is created."""
    db = folder / "store.sqlite"
    try:
        gone = not db.exists() or (db.is_file() and db.stat().st_size == 0)
    except OSError:
        return  # check_own_database names what is wrong with it
    if not gone:
        return
    caches = [n for n in STORE_FILES[1:] if (folder / n).exists()]
    if caches or must_exist:
        what = "is absent" if not db.exists() else "is empty"
        there = f"; {' and '.join(caches)} {'is' if len(caches) == 1 else 'are'} there" if caches else ""
        raise InputError(
            f"{folder}: store missing; nothing was changed ({db.name} {what}{there}: restore it from a "
            "backup, or move the folder aside and ingest again)"
        )
