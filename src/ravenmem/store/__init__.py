"""Stores: see `base.Store`. `local` (FAISS + SQLite, the default) and `milvus` (pymilvus)."""

from __future__ import annotations

from .base import STORES, Store, open_store

__all__ = ["STORES", "Store", "open_store"]


def _load_backends() -> None:
    import importlib

    for mod in ("local", "milvus"):
        try:
            importlib.import_module(f"{__name__}.{mod}")
        except ModuleNotFoundError as e:
            if e.name != f"{__name__}.{mod}":
                raise
