"""Keeping the memory folder's sidecar tables in step with the store.

The store is the source of truth for which memories exist; the sidecars (`lifelong.sqlite`:
consolidated groups, segments) describe stored memories by id. After memories are deleted
their rows go here, and a writer that takes over after a crash settles what a killed
`consolidate` or `forget` left half done (`recover`, called by `Memory.acquire_writer`).
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from ..store.base import Store
from .groups import FILE, GroupTable

if TYPE_CHECKING:
    from ..memory import Memory

log = logging.getLogger(__name__)


def after_delete(mem: Memory, ids: np.ndarray, groups: bool = True) -> None:
    """Drop the sidecar rows of memories the store just deleted."""
    if groups and (mem.path / FILE).exists():
        table = GroupTable(mem.path)
        try:
            table.drop(ids)
        finally:
            table.close()
    mem._groups.invalidate()


def recover(folder: Path, store: Store) -> dict[str, int]:
    """Settle what a killed writer left in the sidecars (nothing to do on a memory without)."""
    if not (folder / FILE).exists():
        return {}
    table = GroupTable(folder)
    try:
        done = table.recover(store)
    finally:
        table.close()
    if any(done.values()):
        log.info("%s: consolidation batches settled: %s", folder, done)
    return done
