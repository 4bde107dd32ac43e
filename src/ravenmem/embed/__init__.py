"""Embedders: see `base.Embedder`. Backends are imported lazily by the registry, so that optional
extras (open_clip, transformers) are only needed when used."""

from __future__ import annotations

from .base import EMBEDDERS, Embedder, create_embedder, l2_normalize

__all__ = ["EMBEDDERS", "Embedder", "create_embedder", "l2_normalize"]
