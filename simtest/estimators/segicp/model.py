"""A tiny U-Net for per-class semantic segmentation of RGB (optionally RGB-D) images (torch).

Encoder stages at strides 2, 4, 8 and 16 (the blocks of :mod:`simtest.estimators.blocks`, trained from
scratch, or ImageNet-pretrained EfficientNet-Lite0 to stride 16 with ``backbone="efficientnet-lite0"``), a decoder
with skip connections back to stride 2, and a 1x1 classifier whose logits are upsampled bilinearly to the
input size. Class 0 is background; class ``c`` (1-based) is the ``c``-th object id of the checkpoint's object
record (sorted ids).

The optional depth channel is the planar depth relative to the median of the image's valid depth, clipped
to +-``DEPTH_RANGE_M`` and divided by it (0 where depth is missing), so the network sees shape, not distance.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import torch
from torch import nn
from torch.nn import functional as F

from simtest.estimators.blocks import Residual, conv_bn_relu, init_conv_weights
from simtest.estimators.efficientnet_lite import FEATURE_CHANNELS, EfficientNetLite0Encoder, load_imagenet_weights
from simtest.estimators.segicp.inputs import DEPTH_RANGE_M

__all__ = ["SegNetConfig", "SegNet", "depth_channel", "net_input", "DEPTH_RANGE_M", "BACKBONES",
           "EFFICIENTNET_WIDTHS"]

#: Encoders of the segmentation network.
BACKBONES = ("plain", "efficientnet-lite0")
#: Channels of EfficientNet-Lite0's feature maps at strides 2, 4, 8, 16.
EFFICIENTNET_WIDTHS = tuple(FEATURE_CHANNELS[:4])


@dataclass(frozen=True)
class SegNetConfig:
    """Architecture of :class:`SegNet` (stored in checkpoints).

    Attributes:
        num_classes: Object classes (background excluded).
        depth_input: Whether depth is a fourth input channel.
        widths: Channels of the encoder stages at strides 2, 4, 8, 16 (the decoder mirrors them).
        backbone: ``"plain"`` (from scratch, ``widths``) or ``"efficientnet-lite0"`` (ImageNet-pretrained, RGB
            only; ``widths`` are then its channels, 16, 24, 40, 112).
    """

    num_classes: int
    depth_input: bool = False
    widths: tuple[int, int, int, int] = (16, 24, 48, 64)
    backbone: str = "plain"

    def __post_init__(self) -> None:
        if self.backbone not in BACKBONES:
            raise ValueError(f"backbone must be one of {', '.join(BACKBONES)}, got {self.backbone!r}")
        if self.backbone != "plain" and (self.depth_input or tuple(self.widths) != EFFICIENTNET_WIDTHS):
            raise ValueError(f"backbone {self.backbone} reads RGB only (depth_input=False) and needs widths "
                             f"{EFFICIENTNET_WIDTHS}, got depth_input={self.depth_input}, widths={self.widths}")

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["widths"] = list(self.widths)
        return d

    @staticmethod
    def from_dict(d: dict[str, Any]) -> "SegNetConfig":
        d = dict(d)
        d["widths"] = tuple(int(w) for w in d["widths"])
        return SegNetConfig(**d)



def depth_channel(depth: torch.Tensor) -> torch.Tensor:
    """(B, 1, H, W) depth in metres -> the normalised relative depth channel (see the module doc)."""
    valid = depth > 0
    out = torch.zeros_like(depth)
    for b in range(depth.shape[0]):
        v = depth[b][valid[b]]
        if v.numel():
            rel = (depth[b] - v.median()).clamp(-DEPTH_RANGE_M, DEPTH_RANGE_M) / DEPTH_RANGE_M
            out[b] = torch.where(valid[b], rel, torch.zeros_like(rel))
    return out


class SegNet(nn.Module):
    """``forward(x)`` takes ``(B, 3 or 4, H, W)``: RGB in [0, 1] (then the depth channel of
    :func:`depth_channel`), ``H`` and ``W`` multiples of 16; returns ``(B, C+1, H, W)`` class logits."""

    MEAN = (0.485, 0.456, 0.406)
    STD = (0.229, 0.224, 0.225)

    def __init__(self, cfg: SegNetConfig) -> None:
        super().__init__()
        self.cfg = cfg
        w1, w2, w3, w4 = cfg.widths
        cin = 4 if cfg.depth_input else 3
        if cfg.backbone == "plain":
            self.stem = nn.Sequential(conv_bn_relu(cin, w1, 2), conv_bn_relu(w1, w1))
            self.s4 = nn.Sequential(conv_bn_relu(w1, w2, 2), Residual(w2))
            self.s8 = nn.Sequential(conv_bn_relu(w2, w3, 2), Residual(w3))
            self.s16 = nn.Sequential(conv_bn_relu(w3, w4, 2), Residual(w4, dilation=2))
        else:  # pretrained weights are loaded by init_weights (training); a checkpoint holds them afterwards
            self.encoder = EfficientNetLite0Encoder(levels=4)
            self.s16 = Residual(w4, dilation=2)  # context beyond the encoder's receptive field, trained from scratch
        self.up8 = conv_bn_relu(w4 + w3, w3)
        self.up4 = conv_bn_relu(w3 + w2, w2)
        self.up2 = conv_bn_relu(w2 + w1, w1)
        self.head = nn.Conv2d(w1, cfg.num_classes + 1, 1)
        self.register_buffer("mean", torch.tensor(self.MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(self.STD).view(1, 3, 1, 1), persistent=False)

    def init_weights(self, generator: torch.Generator) -> None:
        """Deterministic initialisation from ``generator`` (Kaiming convolutions, a small head that starts
        out predicting background); a pretrained encoder is then filled with its ImageNet weights (bit for bit)."""
        init_conv_weights(self, generator)
        if self.cfg.backbone != "plain":
            load_imagenet_weights(self.encoder)
        nn.init.normal_(self.head.weight, std=0.01, generator=generator)
        nn.init.zeros_(self.head.bias)
        with torch.no_grad():
            self.head.bias[0] = 2.0

    @staticmethod
    def _up(x: torch.Tensor, ref: torch.Tensor) -> torch.Tensor:
        return F.interpolate(x, size=ref.shape[-2:], mode="bilinear", align_corners=False)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.cfg.backbone == "plain":
            rgb = (x[:, :3] - self.mean) / self.std
            x = torch.cat([rgb, x[:, 3:]], 1) if self.cfg.depth_input else rgb
            f2 = self.stem(x)
            f4 = self.s4(f2)
            f8 = self.s8(f4)
            f16 = self.s16(f8)
        else:  # the encoder normalises its input as its weights were trained
            f2, f4, f8, f16 = self.encoder(x)
            f16 = self.s16(f16)
        u8 = self.up8(torch.cat([self._up(f16, f8), f8], 1))
        u4 = self.up4(torch.cat([self._up(u8, f4), f4], 1))
        u2 = self.up2(torch.cat([self._up(u4, f2), f2], 1))
        return F.interpolate(self.head(u2), size=x.shape[-2:], mode="bilinear", align_corners=False)


def net_input(rgb: torch.Tensor, depth: torch.Tensor, depth_input: bool, multiple: int = 16) -> torch.Tensor:
    """The network input of a batch: RGB (B, 3, H, W) in [0, 1], plus the depth channel (depth (B, 1, H, W) in
    metres) when asked, padded at the bottom and right to multiples of ``multiple``
    (:func:`~simtest.estimators.segicp.inputs.size_multiple`)."""
    x = torch.cat([rgb, depth_channel(depth)], 1) if depth_input else rgb
    H, W = x.shape[-2:]
    return F.pad(x, (0, (-W) % multiple, 0, (-H) % multiple))
