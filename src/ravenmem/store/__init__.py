"""Stores: see `base.Store`. `local` (FAISS + SQLite, the default) and `milvus` (pymilvus)."""

from __future__ import annotations

from .base import STORES, Store, open_store

__all__ = ["STORES", "Store", "open_store"]
