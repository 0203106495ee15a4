"""Network building blocks shared by the learned estimators' networks (keypoint net, segmentation net; torch)
and their seeded initialisation.

Their module structure is part of every checkpoint's state-dict keys: change a block and old checkpoints stop
loading.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

__all__ = ["conv_bn_relu", "Residual", "init_conv_weights"]


def conv_bn_relu(cin: int, cout: int, stride: int = 1, dilation: int = 1) -> nn.Sequential:
    """3x3 convolution (no bias, padding = dilation, so stride 1 keeps the size), batch norm, ReLU."""
    return nn.Sequential(nn.Conv2d(cin, cout, 3, stride, padding=dilation, dilation=dilation, bias=False),
                         nn.BatchNorm2d(cout), nn.ReLU(inplace=True))


class Residual(nn.Module):
    """``relu(x + bn(conv(conv_bn_relu(x))))`` at ``ch`` channels (two 3x3 convolutions, same size)."""

    def __init__(self, ch: int, dilation: int = 1) -> None:
        super().__init__()
        self.a = conv_bn_relu(ch, ch, dilation=dilation)
        self.b = nn.Sequential(nn.Conv2d(ch, ch, 3, padding=dilation, dilation=dilation, bias=False),
                               nn.BatchNorm2d(ch))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.relu(x + self.b(self.a(x)))


def init_conv_weights(net: nn.Module, generator: torch.Generator) -> None:
    """Deterministic initialisation from ``generator``: Kaiming-normal convolutions (fan out) with zero bias,
    batch norms at identity."""
    for m in net.modules():
        if isinstance(m, nn.Conv2d):
            nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu", generator=generator)
            if m.bias is not None:
                nn.init.zeros_(m.bias)
        elif isinstance(m, nn.BatchNorm2d):
            nn.init.ones_(m.weight)
            nn.init.zeros_(m.bias)
