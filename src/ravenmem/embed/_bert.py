"""A BERT sentence encoder in plain torch, for all-MiniLM-L6-v2's shipped weights: the offline
embedder's `runtime=torch` text side (extra `torch`), the reference the default onnxruntime
encoder (`_bert_onnx.py`) is tested against.

Why not sentence-transformers or transformers: importing either costs seconds (7.6 s for
sentence-transformers on a loaded 2-core machine, 2.6 s for transformers' BertModel on an idle
one), more than the text query they serve. The architecture is small and fixed (embeddings ->
N x [self-attention, feed-forward], post-LayerNorm, exact GELU), the tokenizer is the
`tokenizers` library reading the model's own `tokenizer.json`, and pooling is the model card's
recipe (mean over real tokens, then L2 norm). Parameter names match the checkpoint so loading is
strict: a missing or misshapen tensor is an error, never silent garbage.
`tests/embed/test_text_encoder.py` checks the vectors equal sentence-transformers' output.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from ..errors import RavenmemError
from ._tokens import SentenceFolder


class _Embeddings(nn.Module):
    def __init__(self, vocab: int, dim: int, positions: int, types: int, eps: float) -> None:
        super().__init__()
        self.word_embeddings = nn.Embedding(vocab, dim)
        self.position_embeddings = nn.Embedding(positions, dim)
        self.token_type_embeddings = nn.Embedding(types, dim)
        self.LayerNorm = nn.LayerNorm(dim, eps=eps)

    def forward(self, ids: torch.Tensor) -> torch.Tensor:
        pos = torch.arange(ids.shape[1], device=ids.device)
        x = (
            self.word_embeddings(ids)
            + self.position_embeddings(pos)[None]
            + self.token_type_embeddings.weight[0]
        )
        return self.LayerNorm(x)


class _SelfAttention(nn.Module):
    def __init__(self, dim: int) -> None:
        super().__init__()
        self.query = nn.Linear(dim, dim)
        self.key = nn.Linear(dim, dim)
        self.value = nn.Linear(dim, dim)


class _DenseNorm(nn.Module):
    def __init__(self, din: int, dout: int, eps: float) -> None:
        super().__init__()
        self.dense = nn.Linear(din, dout)
        self.LayerNorm = nn.LayerNorm(dout, eps=eps)

    def forward(self, x: torch.Tensor, residual: torch.Tensor) -> torch.Tensor:
        return self.LayerNorm(self.dense(x) + residual)


class _Attention(nn.Module):
    def __init__(self, dim: int, eps: float) -> None:
        super().__init__()
        self.self = _SelfAttention(dim)
        self.output = _DenseNorm(dim, dim, eps)


class _Intermediate(nn.Module):
    def __init__(self, dim: int, hidden: int) -> None:
        super().__init__()
        self.dense = nn.Linear(dim, hidden)


class _Layer(nn.Module):
    def __init__(self, dim: int, hidden: int, heads: int, eps: float) -> None:
        super().__init__()
        self.heads = heads
        self.attention = _Attention(dim, eps)
        self.intermediate = _Intermediate(dim, hidden)
        self.output = _DenseNorm(hidden, dim, eps)

    def forward(self, x: torch.Tensor, keep: torch.Tensor) -> torch.Tensor:
        n, s, d = x.shape
        att = self.attention.self

        def split(t: torch.Tensor) -> torch.Tensor:
            return t.view(n, s, self.heads, d // self.heads).transpose(1, 2)

        ctx = F.scaled_dot_product_attention(
            split(att.query(x)), split(att.key(x)), split(att.value(x)), keep
        )
        x = self.attention.output(ctx.transpose(1, 2).reshape(n, s, d), x)
        return self.output(F.gelu(self.intermediate.dense(x)), x)


class _Encoder(nn.Module):
    def __init__(self, layers: int, dim: int, hidden: int, heads: int, eps: float) -> None:
        super().__init__()
        self.layer = nn.ModuleList(_Layer(dim, hidden, heads, eps) for _ in range(layers))


class BertEncoder(nn.Module):
    """BertModel's encoder (no pooler) from a Hugging Face `config.json` + `model.safetensors`."""

    def __init__(self, config: dict) -> None:
        super().__init__()
        if (
            config.get("hidden_act", "gelu") != "gelu"
            or config.get("position_embedding_type", "absolute") != "absolute"
        ):
            raise RavenmemError("BertEncoder supports gelu activations and absolute positions only")
        dim, eps = int(config["hidden_size"]), float(config["layer_norm_eps"])
        if dim % int(config["num_attention_heads"]):
            raise RavenmemError(f"BertEncoder: hidden size {dim} does not split over the attention heads")
        self.dim = dim
        self.embeddings = _Embeddings(
            int(config["vocab_size"]),
            dim,
            int(config["max_position_embeddings"]),
            int(config["type_vocab_size"]),
            eps,
        )
        self.encoder = _Encoder(
            int(config["num_hidden_layers"]),
            dim,
            int(config["intermediate_size"]),
            int(config["num_attention_heads"]),
            eps,
        )

    def forward(self, ids: torch.Tensor, mask: torch.Tensor) -> torch.Tensor:
        """Token ids and 0/1 attention mask (N, S) -> mean-pooled (N, dim), not normalised."""
        keep = mask.bool()[:, None, None, :]  # (N, 1, 1, S): queries may attend to real tokens only
        x = self.embeddings(ids)
        for layer in self.encoder.layer:
            x = layer(x, keep)
        m = mask.to(x.dtype)[..., None]
        return (x * m).sum(dim=1) / m.sum(dim=1).clamp(min=1e-9)


class SentenceEncoder:
    """Tokenizer + BertEncoder + mean pooling, loaded from a sentence-transformers model folder."""

    def __init__(self, folder: Path, max_length: int | None = None) -> None:
        from safetensors.torch import load_file

        self.model = SentenceFolder(folder, max_length)
        try:
            weights = load_file(str(self.model.weights))
        except (OSError, ValueError, Exception) as e:  # safetensors raises SafetensorError
            raise RavenmemError(f"text model in {folder} is unreadable: {e}") from e
        self.encoder = BertEncoder(self.model.config)
        weights = {
            k: v for k, v in weights.items() if not k.startswith("pooler.") and k != "embeddings.position_ids"
        }
        try:
            # assign: keep the memory-mapped tensors instead of copying them, so only the rows of
            # the 30k-word embedding table that queries use are ever read from disk
            self.encoder.load_state_dict(weights, strict=True, assign=True)
        except RuntimeError as e:
            raise RavenmemError(f"{self.model.weights}: does not fit BERT ({e})") from e
        self.encoder.eval()

    def encode(self, texts: Sequence[str], batch_size: int = 128) -> np.ndarray:
        """(N, dim) float32 mean-pooled embeddings (not normalised), in input order."""

        def forward(ids: np.ndarray, mask: np.ndarray) -> np.ndarray:
            with torch.inference_mode():
                return self.encoder(torch.from_numpy(ids), torch.from_numpy(mask)).float().numpy()

        return self.model.encode(texts, forward, batch_size)
