"""The embedder axis: images and texts into one vector space, cosine-comparable.

Every backend returns L2-normalised float32 rows so that inner product == cosine similarity,
which is what the stores index. `name` must identify the model and its settings precisely
enough that two memories built with the same name are comparable: it is stored in the memory
and checked on open.
"""

from __future__ import annotations

import os
from collections.abc import Sequence
from pathlib import Path
from typing import Protocol, runtime_checkable

import numpy as np

from ..errors import RavenmemError
from ..registry import Registry

MAX_DEFAULT_THREADS = 4


def default_threads() -> int:
    """The intra-op threads an embedder uses unless told: every core up to 4 (beyond 4 this
    network gains little), `$RAVENMEM_THREADS` if set."""
    env = os.environ.get("RAVENMEM_THREADS", "").strip()
    if env:
        try:
            n = int(env)
        except ValueError:
            raise RavenmemError(f"RAVENMEM_THREADS={env!r} is not a whole number") from None
        if n >= 1:
            return n
    return max(1, min(MAX_DEFAULT_THREADS, os.cpu_count() or 1))


def cache_dir() -> Path:
    """Where embedders keep what they build once from packaged weights (ONNX graphs, label
    banks): `$RAVENMEM_CACHE_DIR`, else `$XDG_CACHE_HOME/ravenmem`, else `~/.cache/ravenmem`."""
    if os.environ.get("RAVENMEM_CACHE_DIR"):
        return Path(os.environ["RAVENMEM_CACHE_DIR"])
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base) / "ravenmem"


@runtime_checkable
class Embedder(Protocol):
    @property
    def name(self) -> str: ...

    @property
    def dim(self) -> int: ...

    def embed_images(self, images: Sequence[np.ndarray]) -> np.ndarray:
        """RGB uint8 (H, W, 3) images -> (N, dim) float32, rows L2-normalised."""
        ...

    def embed_texts(self, texts: Sequence[str]) -> np.ndarray:
        """Texts -> (N, dim) float32, rows L2-normalised, in the same space as images."""
        ...


EMBEDDERS: Registry[Embedder] = Registry(
    "embedder",
    "ravenmem.embedders",
    {"offline": "ravenmem.embed.offline", "open_clip": "ravenmem.embed.open_clip", "hf": "ravenmem.embed.hf"},
)


def l2_normalize(x: np.ndarray) -> np.ndarray:
    x = np.asarray(x, dtype=np.float32)
    n = np.linalg.norm(x, axis=-1, keepdims=True)
    return (x / np.maximum(n, 1e-12)).astype(np.float32)


def create_embedder(spec: str = "offline", **kwargs: object) -> Embedder:
    """Create an embedder by spec: `offline`, `open_clip:MODEL/PRETRAINED`, `hf:NAME_OR_PATH`, ..."""
    return EMBEDDERS.create(spec, **kwargs)
