"""A sentence-transformers model folder's configuration, tokenizer and length-sorted batches,
shared by the onnxruntime encoder (`_bert_onnx.py`, the default) and the torch one (`_bert.py`).

The tokenizer is the `tokenizers` library reading the model's own `tokenizer.json`, truncating
at the model's `max_seq_length`. Texts are batched by token count (least padding); padding never
changes a vector because the encoders mask it.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import RavenmemError


class SentenceFolder:
    """`config.json`, `sentence_bert_config.json` and `tokenizer.json` of a model folder."""

    def __init__(self, folder: Path, max_length: int | None = None) -> None:
        from tokenizers import Tokenizer

        self.folder = folder
        try:
            self.config: dict[str, Any] = json.loads((folder / "config.json").read_text(encoding="utf-8"))
            st_config = folder / "sentence_bert_config.json"
            if max_length is None and st_config.exists():
                max_length = int(json.loads(st_config.read_text(encoding="utf-8"))["max_seq_length"])
            self.tokenizer = Tokenizer.from_file(str(folder / "tokenizer.json"))
            self.max_length = int(max_length or self.config["max_position_embeddings"])
            self.dim = int(self.config["hidden_size"])
        except Exception as e:  # OSError, bad JSON, missing keys; tokenizers raises plain Exception
            raise RavenmemError(f"text model in {folder} is unreadable: {e}") from e
        self.tokenizer.enable_truncation(self.max_length)
        self.tokenizer.no_padding()  # padded per batch below, to the batch's longest text

    @property
    def weights(self) -> Path:
        return self.folder / "model.safetensors"

    def encode(
        self, texts: Sequence[str], forward: Callable[[np.ndarray, np.ndarray], np.ndarray], batch_size: int
    ) -> np.ndarray:
        """(N, dim) float32: `forward(ids, mask)` ((n, S) int64 each -> (n, dim)) over batches of
        similar length, results in input order."""
        enc = self.tokenizer.encode_batch(list(texts))
        order = np.argsort([-len(e.ids) for e in enc], kind="stable")
        out = np.zeros((len(texts), self.dim), dtype=np.float32)
        for s in range(0, len(order), batch_size):
            idx = order[s : s + batch_size]
            width = max(len(enc[i].ids) for i in idx)
            ids = np.zeros((len(idx), width), dtype=np.int64)
            mask = np.zeros((len(idx), width), dtype=np.int64)
            for row, i in enumerate(idx):
                n = len(enc[i].ids)
                ids[row, :n] = enc[i].ids
                mask[row, :n] = 1
            out[idx] = forward(ids, mask)
        return out
