"""A compact fully-convolutional encoder-decoder with a segmentation head and a keypoint head (torch).

Output grid: one cell per ``stride`` x ``stride`` input pixels (stride 4). Cell ``(i, j)`` has its centre at
pixel ``(stride * j + (stride - 1) / 2, stride * i + (stride - 1) / 2)`` (OpenCV pixel-centre convention).

Heads, per cell:

* ``seg``: ``num_classes + 1`` logits (class 0 is background);
* ``offsets``: ``2 J`` values, the offset of each of the ``J`` projected keypoints from the cell centre in
  units of ``offset_scale`` pixels, ordered ``(dx_0, dy_0, dx_1, dy_1, ...)``;
* ``conf``: ``J`` logits ``z``; the confidence is ``c = log(1 / (1 - sigmoid(z))) = softplus(z)``.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import torch
from torch import nn
from torch.nn import functional as F

from simtest.estimators.blocks import Residual, conv_bn_relu, init_conv_weights

__all__ = ["NetConfig", "KeypointNet", "cell_centers"]


@dataclass(frozen=True)
class NetConfig:
    """Architecture of :class:`KeypointNet` (stored in checkpoints).

    Attributes:
        num_classes: Object classes (background excluded).
        num_keypoints: Keypoints per object (8 bbox corners by default).
        widths: Channels of the four encoder stages (strides 2, 4, 8, 16).
        decoder: Channels of the decoder at strides 8 and 4.
        offset_scale: Pixels per unit of the predicted offsets.
    """

    num_classes: int
    num_keypoints: int = 8
    widths: tuple[int, int, int, int] = (16, 32, 64, 96)
    decoder: tuple[int, int] = (64, 48)
    offset_scale: float = 32.0
    stride: int = 4

    def to_dict(self) -> dict[str, Any]:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in asdict(self).items()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> "NetConfig":
        d = {k: (tuple(v) if isinstance(v, list) else v) for k, v in d.items()}  # JSON and checkpoints give lists
        return cls(**d)


class KeypointNet(nn.Module):
    """Encoder (strides 2..16) and a U-Net-style decoder back to stride 4, with two heads.

    ``forward(x)`` takes ``(B, 3, H, W)`` RGB in [0, 1] (H, W multiples of 16) and returns a dict of
    ``seg`` (B, C+1, H/4, W/4), ``offsets`` (B, J, 2, H/4, W/4) and ``conf_logit`` (B, J, H/4, W/4).
    """

    #: ImageNet statistics, used only to centre the input.
    MEAN = (0.485, 0.456, 0.406)
    STD = (0.229, 0.224, 0.225)

    def __init__(self, cfg: NetConfig) -> None:
        super().__init__()
        if cfg.stride != 4:
            raise ValueError(f"only stride 4 is built, got {cfg.stride}")
        self.cfg = cfg
        w1, w2, w3, w4 = cfg.widths
        d8, d4 = cfg.decoder
        self.stem = nn.Sequential(conv_bn_relu(3, w1, 2), conv_bn_relu(w1, w1))
        self.s4 = nn.Sequential(conv_bn_relu(w1, w2, 2), Residual(w2))
        self.s8 = nn.Sequential(conv_bn_relu(w2, w3, 2), Residual(w3))
        self.s16 = nn.Sequential(conv_bn_relu(w3, w4, 2), Residual(w4, dilation=2))
        self.up8 = conv_bn_relu(w4 + w3, d8)
        self.up4 = nn.Sequential(conv_bn_relu(d8 + w2, d4), conv_bn_relu(d4, d4))
        J = cfg.num_keypoints
        self.seg_head = nn.Sequential(conv_bn_relu(d4, d4), nn.Conv2d(d4, cfg.num_classes + 1, 1))
        self.kp_head = nn.Sequential(conv_bn_relu(d4, d4), nn.Conv2d(d4, 3 * J, 1))
        self.register_buffer("mean", torch.tensor(self.MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(self.STD).view(1, 3, 1, 1), persistent=False)

    def init_weights(self, generator: torch.Generator) -> None:
        """Deterministic initialisation from ``generator`` (Kaiming for convolutions; small heads)."""
        init_conv_weights(self, generator)
        for head in (self.seg_head[-1], self.kp_head[-1]):
            nn.init.normal_(head.weight, std=0.01, generator=generator)
            nn.init.zeros_(head.bias)
        with torch.no_grad():  # start with a confident background and moderate keypoint confidences
            self.seg_head[-1].bias[0] = 2.0

    def forward(self, x: torch.Tensor) -> dict[str, torch.Tensor]:
        x = (x - self.mean) / self.std
        f2 = self.stem(x)
        f4 = self.s4(f2)
        f8 = self.s8(f4)
        f16 = self.s16(f8)
        u8 = self.up8(torch.cat([F.interpolate(f16, size=f8.shape[-2:], mode="bilinear", align_corners=False), f8], 1))
        u4 = self.up4(torch.cat([F.interpolate(u8, size=f4.shape[-2:], mode="bilinear", align_corners=False), f4], 1))
        seg = self.seg_head(u4)
        kp = self.kp_head(u4)
        B, _, h, w = kp.shape
        J = self.cfg.num_keypoints
        return {"seg": seg, "offsets": kp[:, :2 * J].reshape(B, J, 2, h, w), "conf_logit": kp[:, 2 * J:]}


def cell_centers(h: int, w: int, stride: int, device: Any = None, dtype: Any = torch.float32) -> torch.Tensor:
    """(2, h, w) pixel coordinates (x, y) of the cell centres of an ``h x w`` grid at ``stride``."""
    ys = torch.arange(h, device=device, dtype=dtype) * stride + (stride - 1) / 2.0
    xs = torch.arange(w, device=device, dtype=dtype) * stride + (stride - 1) / 2.0
    gy, gx = torch.meshgrid(ys, xs, indexing="ij")
    return torch.stack([gx, gy])
