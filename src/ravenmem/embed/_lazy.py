"""The shell shared by embedders that wrap a third-party torch model (open_clip, transformers).

Loading such a model takes seconds and may need an optional extra, so it happens on first use
(an embed call or `dim`), once, under a lock. Input checks and empty batches are handled here;
a backend supplies `_load_model` (returns the output dim) and the two `_encode_*` methods.
"""

from __future__ import annotations

import threading
from abc import ABC, abstractmethod
from collections.abc import Sequence

import numpy as np

from ..errors import InputError
from .tiles import check_image


class LazyTorchEmbedder(ABC):
    device: str | None

    def __init__(self, device: str | None = None) -> None:
        self.device = device
        self._lock = threading.Lock()
        self._dim: int | None = None

    @abstractmethod
    def _load_model(self) -> int:
        """Load the model onto `self.device` (None: cuda if available) and return its dim."""

    @abstractmethod
    def _encode_images(self, images: list[np.ndarray]) -> np.ndarray:
        """Checked RGB uint8 images -> (N, dim) L2-normalised float32."""

    @abstractmethod
    def _encode_texts(self, texts: list[str]) -> np.ndarray:
        """Texts -> (N, dim) L2-normalised float32, in the images' space."""

    def _load(self) -> None:
        with self._lock:
            if self._dim is None:
                self._dim = self._load_model()

    @property
    def dim(self) -> int:
        self._load()
        assert self._dim is not None
        return self._dim

    def embed_images(self, images: Sequence[np.ndarray]) -> np.ndarray:
        self._load()
        if len(images) == 0:
            return np.zeros((0, self.dim), dtype=np.float32)
        return self._encode_images([check_image(im, i) for i, im in enumerate(images)])

    def embed_texts(self, texts: Sequence[str]) -> np.ndarray:
        if isinstance(texts, str) or not all(isinstance(t, str) for t in texts):
            raise InputError("embed_texts: expected a list of strings")
        self._load()
        if len(texts) == 0:
            return np.zeros((0, self.dim), dtype=np.float32)
        return self._encode_texts(list(texts))
