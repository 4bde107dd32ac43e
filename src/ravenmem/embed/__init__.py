"""Embedders: see `base.Embedder`. Backends are imported lazily so that optional extras
(open_clip, transformers) are only needed when used."""

from __future__ import annotations

from .base import EMBEDDERS, Embedder, create_embedder, l2_normalize

__all__ = ["EMBEDDERS", "Embedder", "create_embedder", "l2_normalize"]


def _load_backends() -> None:
    """Import backend modules so their @EMBEDDERS.register decorators run."""
    import importlib

    for mod in ("offline", "open_clip", "hf"):
        try:
            importlib.import_module(f"{__name__}.{mod}")
        except ModuleNotFoundError as e:
            if e.name != f"{__name__}.{mod}":
                raise
