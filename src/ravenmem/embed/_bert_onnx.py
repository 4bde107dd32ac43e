"""all-MiniLM-L6-v2 (a BERT encoder) as an ONNX graph run by onnxruntime: the offline text side
without torch or sentence-transformers.

The graph is built from the model folder's `config.json` and `model.safetensors` (read with
`safetensors.numpy`): embeddings (word + position + token type 0) -> LayerNorm -> N x
[multi-head self-attention, feed-forward with exact GELU], post-LayerNorm, then the model card's
pooling (mean over real tokens). Padding is masked out of attention and pooling, so a batch's
padding never changes a vector. `tests/embed/test_onnx.py` checks the vectors against the torch
encoder (`_bert.py`) and, where installed, sentence-transformers.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..errors import RavenmemError
from . import _onnx
from ._tokens import SentenceFolder

GRAPH_VERSION = 1  # bump when the graph below changes: it names the cached file
MASKED = -1e30  # added to the attention scores of padding: exp() of it is exactly 0


def build_graph(config: dict[str, Any], weights: dict[str, np.ndarray], what: str = "bert") -> Any:
    """Inputs `input_ids`, `attention_mask` (N, S) int64; output `pooled` (N, hidden) float32."""
    from onnx import TensorProto, helper

    if (
        config.get("hidden_act", "gelu") != "gelu"
        or config.get("position_embedding_type", "absolute") != "absolute"
    ):
        raise RavenmemError(f"{what}: only gelu activations and absolute positions are supported")
    dim, heads = int(config["hidden_size"]), int(config["num_attention_heads"])
    if dim % heads:
        raise RavenmemError(f"{what}: hidden size {dim} does not split over {heads} attention heads")
    eps = float(config["layer_norm_eps"])
    g = _onnx.GraphBuilder()

    def w(name: str) -> np.ndarray:
        if name not in weights:
            raise RavenmemError(f"{what}: tensor {name} missing from the weights")
        return weights[name]

    def linear(x: str, name: str) -> str:
        return g.node(
            "Add", [g.node("MatMul", [x, g.const(w(f"{name}.weight").T)]), g.const(w(f"{name}.bias"))]
        )

    def norm(x: str, name: str) -> str:
        return g.node(
            "LayerNormalization",
            [x, g.const(w(f"{name}.weight")), g.const(w(f"{name}.bias"))],
            axis=-1,
            epsilon=eps,
        )

    i64 = np.int64
    seq = g.node("Slice", [g.node("Shape", ["input_ids"]), g.const([1], i64), g.const([2], i64)])
    pos = g.node(
        "Slice",
        [g.const(w("embeddings.position_embeddings.weight")), g.const([0], i64), seq, g.const([0], i64)],
    )
    x = g.node("Gather", [g.const(w("embeddings.word_embeddings.weight")), "input_ids"])
    x = g.node("Add", [g.node("Add", [x, pos]), g.const(w("embeddings.token_type_embeddings.weight")[0])])
    x = norm(x, "embeddings.LayerNorm")
    maskf = g.node("Cast", ["attention_mask"], to=TensorProto.FLOAT)
    # (N, 1, 1, S): 0 for real tokens, MASKED for padding
    bias = g.node(
        "Unsqueeze",
        [g.node("Mul", [g.node("Sub", [g.const(1.0), maskf]), g.const(MASKED)]), g.const([1, 2], i64)],
    )
    split = g.const([0, 0, heads, dim // heads], i64)
    merge = g.const([0, 0, dim], i64)
    scale = g.const(1.0 / np.sqrt(dim // heads))
    for n in range(int(config["num_hidden_layers"])):
        p = f"encoder.layer.{n}."

        def heads_of(t: str, perm: list[int]) -> str:
            return g.node("Transpose", [g.node("Reshape", [t, split])], perm=perm)

        q = heads_of(linear(x, f"{p}attention.self.query"), [0, 2, 1, 3])
        k = heads_of(linear(x, f"{p}attention.self.key"), [0, 2, 3, 1])
        v = heads_of(linear(x, f"{p}attention.self.value"), [0, 2, 1, 3])
        scores = g.node("Add", [g.node("Mul", [g.node("MatMul", [q, k]), scale]), bias])
        ctx = g.node("MatMul", [g.node("Softmax", [scores], axis=-1), v])
        ctx = g.node("Reshape", [g.node("Transpose", [ctx], perm=[0, 2, 1, 3]), merge])
        x = norm(
            g.node("Add", [linear(ctx, f"{p}attention.output.dense"), x]), f"{p}attention.output.LayerNorm"
        )
        h = linear(x, f"{p}intermediate.dense")
        # exact GELU: h * 0.5 * (1 + erf(h / sqrt(2)))
        erf = g.node("Erf", [g.node("Mul", [h, g.const(1.0 / np.sqrt(2.0))])])
        h = g.node("Mul", [g.node("Mul", [h, g.const(0.5)]), g.node("Add", [erf, g.const(1.0)])])
        x = norm(g.node("Add", [linear(h, f"{p}output.dense"), x]), f"{p}output.LayerNorm")
    m = g.node("Unsqueeze", [maskf, g.const([2], i64)])  # (N, S, 1)
    total = g.node("ReduceSum", [g.node("Mul", [x, m]), g.const([1], i64)], keepdims=0)
    count = g.node("Max", [g.node("ReduceSum", [m, g.const([1], i64)], keepdims=0), g.const(1e-9)])
    g.node("Div", [total, count], name="pooled")
    return g.model(
        "bert_mean_pooled",
        [
            helper.make_tensor_value_info("input_ids", TensorProto.INT64, ["N", "S"]),
            helper.make_tensor_value_info("attention_mask", TensorProto.INT64, ["N", "S"]),
        ],
        [helper.make_tensor_value_info("pooled", TensorProto.FLOAT, ["N", dim])],
    )


class SentenceEncoderOnnx:
    """Tokenizer + the BERT graph + mean pooling, from a sentence-transformers model folder."""

    def __init__(self, folder: Path, threads: int | None = None) -> None:
        self.model = SentenceFolder(folder)
        src = self.model.weights

        def build() -> Any:
            from safetensors.numpy import load_file

            try:
                weights = load_file(str(src))
            except (OSError, ValueError, Exception) as e:  # safetensors raises SafetensorError
                raise RavenmemError(f"{src}: unreadable weights ({e})") from e
            return build_graph(self.model.config, weights, str(src))

        key = [GRAPH_VERSION, self.model.config, _onnx.fingerprint(src)]
        self.session = _onnx.cached_session("minilm-fp32", key, build, threads)

    def encode(self, texts: list[str], batch_size: int = 128) -> np.ndarray:
        """(N, dim) float32 mean-pooled embeddings (not normalised), in input order."""

        def forward(ids: np.ndarray, mask: np.ndarray) -> np.ndarray:
            return self.session.run(["pooled"], {"input_ids": ids, "attention_mask": mask})[0]

        return self.model.encode(texts, forward, batch_size)
