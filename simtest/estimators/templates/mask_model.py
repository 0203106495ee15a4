"""The outline network (torch): a crop around a posed object and the pose's silhouette in, the object's visible
mask out.

A pose found by template matching is often right in rotation and a few percent off in depth and position. A
silhouette fit pins the depth well when it is given the object's exact visible mask (on the first 25 real LM-O
frames: 53.5 % ADD(-S)-0.1d against 34.8 % without the fit, with ground-truth masks), and badly when given a
detector's coarse region. This network makes the mask: it sees the crop through ImageNet-pretrained
EfficientNet-Lite0 features (frozen: they were never trained on renders) and the pose's silhouette (the
*prior*) at every decoder stage, and it learns on simtest renders to move the prior's outline onto the
object's visible pixels (occluders cut out).

``forward(x)`` takes ``(B, 4, S, S)``: RGB in [0, 1], then the prior (1 inside the pose's silhouette, else 0),
``S`` a multiple of 32; it returns ``(B, 1, S, S)`` mask logits (the visible mask is ``logits > 0``).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any

import torch
from torch import nn
from torch.nn import functional as F

from simtest.estimators.blocks import init_conv_weights
from simtest.estimators.efficientnet_lite import FEATURE_CHANNELS, EfficientNetLite0Encoder, load_imagenet_weights

__all__ = ["MaskNetConfig", "MaskNet"]


@dataclass(frozen=True)
class MaskNetConfig:
    """Architecture of :class:`MaskNet` (stored in checkpoints).

    Attributes:
        crop_size: Side of the square crops (pixels, a multiple of 32).
        widths: Decoder channels at strides 16, 8, 4, 2 and 1.
        image_skip: The decoder's last stage sees the crop's own pixels beside the upsampled decoder and the
            prior (as the shipped network). Off, it sees the pretrained features only: no trained layer then
            reads raw pixel values, which differ most between renders and a camera's images.
    """

    crop_size: int = 128
    widths: tuple[int, int, int, int, int] = (64, 48, 32, 24, 16)
    image_skip: bool = True

    def __post_init__(self) -> None:
        if int(self.crop_size) < 32 or int(self.crop_size) % 32:
            raise ValueError(f"crop_size must be a positive multiple of 32 pixels, got {self.crop_size!r}")
        if len(self.widths) != 5 or min(self.widths) < 1:
            raise ValueError(f"widths must be five positive channel counts, got {self.widths!r}")

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["widths"] = list(self.widths)
        return d

    @staticmethod
    def from_dict(d: dict[str, Any]) -> "MaskNetConfig":
        d = dict(d)
        d["widths"] = tuple(int(w) for w in d["widths"])
        return MaskNetConfig(**d)


def _block(cin: int, cout: int) -> nn.Sequential:
    return nn.Sequential(nn.Conv2d(cin, cout, 3, padding=1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True),
                         nn.Conv2d(cout, cout, 3, padding=1, bias=False), nn.BatchNorm2d(cout), nn.ReLU(inplace=True))


class MaskNet(nn.Module):
    """See the module doc. The encoder is frozen (no gradients, batch norms at their ImageNet statistics)."""

    def __init__(self, cfg: MaskNetConfig) -> None:
        super().__init__()
        self.cfg = cfg
        c2, c4, c8, c16 = FEATURE_CHANNELS[:4]
        w16, w8, w4, w2, w1 = cfg.widths
        self.encoder = EfficientNetLite0Encoder(levels=4)
        for p in self.encoder.parameters():
            p.requires_grad = False
        self.d16 = _block(c16 + 1, w16)
        self.d8 = _block(w16 + c8 + 1, w8)
        self.d4 = _block(w8 + c4 + 1, w4)
        self.d2 = _block(w4 + c2 + 1, w2)
        self.d1 = _block(w2 + (3 if cfg.image_skip else 0) + 1, w1)
        self.head = nn.Conv2d(w1, 1, 1)

    def init_weights(self, generator: torch.Generator) -> None:
        """Deterministic initialisation from ``generator``; the encoder then holds its ImageNet weights."""
        init_conv_weights(self, generator)
        load_imagenet_weights(self.encoder)

    def train(self, mode: bool = True) -> "MaskNet":
        super().train(mode)
        self.encoder.eval()  # frozen: its batch norms keep the ImageNet statistics
        return self

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        rgb, prior = x[:, :3], x[:, 3:4]
        with torch.no_grad():
            f2, f4, f8, f16 = self.encoder(rgb)

        y = self.d16(torch.cat([f16, F.avg_pool2d(prior, 16)], 1))
        for block, f, stride in ((self.d8, f8, 8), (self.d4, f4, 4), (self.d2, f2, 2)):
            y = F.interpolate(y, size=f.shape[-2:], mode="bilinear", align_corners=False)
            y = block(torch.cat([y, f, F.avg_pool2d(prior, stride)], 1))
        y = F.interpolate(y, size=x.shape[-2:], mode="bilinear", align_corners=False)
        last = [y, rgb, prior] if self.cfg.image_skip else [y, prior]
        return self.head(self.d1(torch.cat(last, 1)))
