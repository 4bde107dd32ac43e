"""EfficientNet-Lite0 as plain PyTorch modules (no timm: timm needs torchvision, and PyPI has no
torchvision build that runs on the CPU-only torch this project installs).

Lite variants drop squeeze-excitation, use ReLU6 and keep the stem (32) and head (1280) widths
fixed. Padding is symmetric (k // 2). The parameter order is the one the packaged lukemelas-style
state dict uses, so weights are loaded by position with every shape checked (see `_effnet.py`).
"""

from __future__ import annotations

import torch
from torch import nn

# (repeats, kernel, stride, expand ratio, out channels) per stage
STAGES = [
    (1, 3, 1, 1, 16),
    (2, 3, 2, 6, 24),
    (2, 5, 2, 6, 40),
    (3, 3, 2, 6, 80),
    (3, 5, 1, 6, 112),
    (4, 5, 2, 6, 192),
    (1, 3, 1, 6, 320),
]
STEM, HEAD = 32, 1280


def _conv_bn(
    cin: int, cout: int, k: int, stride: int = 1, groups: int = 1, act: bool = True
) -> list[nn.Module]:
    layers: list[nn.Module] = [
        nn.Conv2d(cin, cout, k, stride, k // 2, groups=groups, bias=False),
        nn.BatchNorm2d(cout, eps=1e-5),
    ]
    if act:
        layers.append(nn.ReLU6(inplace=True))
    return layers


class MBConv(nn.Module):
    """Inverted residual block (expand 1x1 -> depthwise kxk -> project 1x1), skip when shapes allow."""

    def __init__(self, cin: int, cout: int, k: int, stride: int, expand: int) -> None:
        super().__init__()
        mid = cin * expand
        layers = _conv_bn(cin, mid, 1) if expand != 1 else []
        layers += _conv_bn(mid, mid, k, stride, groups=mid) + _conv_bn(mid, cout, 1, act=False)
        self.body = nn.Sequential(*layers)
        self.skip = stride == 1 and cin == cout

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        y = self.body(x)
        return x + y if self.skip else y


class EfficientNetLite0(nn.Module):
    """`forward` returns (pooled 1280-d features, 1000 class logits)."""

    def __init__(self, num_classes: int = 1000) -> None:
        super().__init__()
        blocks: list[nn.Module] = list(_conv_bn(3, STEM, 3, 2))
        cin = STEM
        for repeats, k, stride, expand, cout in STAGES:
            for i in range(repeats):
                blocks.append(MBConv(cin, cout, k, stride if i == 0 else 1, expand))
                cin = cout
        blocks += _conv_bn(cin, HEAD, 1)
        self.features = nn.Sequential(*blocks)
        self.classifier = nn.Linear(HEAD, num_classes)

    def forward(self, x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        feats = self.features(x).mean(dim=(2, 3))
        return feats, self.classifier(feats)
