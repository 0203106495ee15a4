"""The crop network of the keypoint estimator (torch): one zoom-in crop of a detected object in, per stride-4
cell and per object class an object-mask logit, the offsets of the ``J`` projected keypoints and their
confidence logits out.

The class heads are separate: for a crop of class ``c`` (from the detector) only class ``c``'s channels are read
(:func:`select_class`), so one network serves every object and two objects in one crop do not compete.
Cell ``(i, j)`` has its centre at crop pixel ``(4 j + 1.5, 4 i + 1.5)`` (OpenCV pixel centres); offsets are in
units of ``offset_scale`` crop pixels; the confidence is ``c = softplus(z)`` as in :mod:`.loss`.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import nn
from torch.nn import functional as F

from simtest.estimators.blocks import Residual, conv_bn_relu, init_conv_weights
from simtest.estimators.efficientnet_lite import EfficientNetLite0Encoder, load_imagenet_weights
from simtest.estimators.keypoints.loss import C_MAX, confidence
from simtest.estimators.keypoints.model import KeypointNet, NetConfig, cell_centers

__all__ = ["CropNetConfig", "CropKeypointNet", "select_class", "select_class_xyz", "crop_targets", "crop_loss",
           "xyz_loss", "BACKBONES", "EFFICIENTNET_WIDTHS"]

#: Encoders of the crop network.
BACKBONES = ("plain", "efficientnet-lite0")
#: Channels of EfficientNet-Lite0's feature maps at strides 2, 4, 8, 16.
EFFICIENTNET_WIDTHS = (16, 24, 40, 112)


@dataclass(frozen=True)
class CropNetConfig(NetConfig):
    """Architecture and crop geometry of :class:`CropKeypointNet` (stored in checkpoints and ONNX files).

    Attributes:
        num_classes: Object classes. num_keypoints: Keypoints per object.
        widths: Channels of the encoder stages at strides 2, 4, 8, 16. decoder: Decoder channels at 8 and 4.
        offset_scale: Crop pixels per unit of the predicted offsets. stride: Output stride (4).
        crop_size: Crop side the network is trained on (pixels). margin: Crop window side / box side.
        coords: Append the cells' crop coordinates (x, y in [-1, 1]) to the stride-16 features and to the heads'
            input, so the offsets from each cell (linear in its position) are easy to regress.
        dense: Add the object-coordinate head: per cell and class the 3D point of the object surface the cell
            sees, in the (symmetry-canonical) model frame, and a confidence logit; these dense 2D-3D
            correspondences give the pose by PnP-RANSAC (:mod:`.crop_infer`).
        xyz_scale: Per class, metres per unit of the predicted object coordinates (half the object's diameter).
        hypotheses: Object-coordinate hypotheses per cell and class, trained winner-takes-all per crop: an
            object that looks (nearly) the same in two poses (a mug with its handle hidden, a banana turned
            over) gets one consistent map per pose instead of their average, which fits neither; inference
            keeps the hypothesis PnP explains best.
        backbone: The encoder: ``"plain"`` (trained from scratch, ``widths``) or ``"efficientnet-lite0"``
            (ImageNet-pretrained EfficientNet-Lite0 to stride 16, :mod:`simtest.estimators.efficientnet_lite`;
            ``widths`` must be its channels, :data:`EFFICIENTNET_WIDTHS`; crop side a multiple of 32).
    """

    # the whole-image network's fields (num_classes .. stride, same defaults), then the crop's
    crop_size: int = 128
    margin: float = 1.3
    coords: bool = True
    dense: bool = False
    xyz_scale: tuple[float, ...] = ()
    hypotheses: int = 1
    backbone: str = "plain"

    def __post_init__(self) -> None:
        if self.backbone not in BACKBONES:
            raise ValueError(f"backbone must be one of {', '.join(BACKBONES)}, got {self.backbone!r}")
        if self.backbone != "plain" and (tuple(self.widths) != EFFICIENTNET_WIDTHS or self.crop_size % 32):
            raise ValueError(f"backbone {self.backbone} needs widths {EFFICIENTNET_WIDTHS} and a crop side that is a "
                             f"multiple of 32, got widths {tuple(self.widths)} and crop {self.crop_size}")
        if self.dense and len(self.xyz_scale) != self.num_classes:
            raise ValueError(f"a dense crop network needs one xyz_scale per class ({self.num_classes}), got "
                             f"{self.xyz_scale!r}")
        if self.hypotheses < 1:
            raise ValueError(f"hypotheses must be >= 1, got {self.hypotheses!r}")


class CropKeypointNet(nn.Module):
    """Encoder (strides 2..16, dilated last stage) and a decoder with skips back to stride 4.

    ``forward(x)`` takes ``(B, 3, S, S)`` RGB in [0, 1] (S a multiple of 16) and returns ``fg`` (B, C, S/4, S/4)
    object-mask logits and ``kp`` (B, C * 3 J, S/4, S/4): per class ``c`` the ``2 J`` offsets
    ``(dx_0, dy_0, ...)`` then the ``J`` confidence logits, at channels ``[3 J c, 3 J (c + 1))``; with
    ``cfg.dense`` also ``xyz`` (B, 4 H C, S/4, S/4): per class and hypothesis the object coordinates
    ``(x, y, z)`` in units of ``xyz_scale[c]`` and a confidence logit, at channels ``[4 (H c + k), 4 (H c + k + 1))``
    (``H = cfg.hypotheses``, hypothesis ``k``).
    """

    MEAN, STD = KeypointNet.MEAN, KeypointNet.STD  # ImageNet statistics, only to centre the input

    def __init__(self, cfg: CropNetConfig) -> None:
        super().__init__()
        if cfg.stride != 4:
            raise ValueError(f"only stride 4 is built, got {cfg.stride}")
        self.cfg = cfg
        w1, w2, w3, w4 = cfg.widths
        d8, d4 = cfg.decoder
        e = 2 if cfg.coords else 0
        if cfg.backbone == "plain":
            self.stem = nn.Sequential(conv_bn_relu(3, w1, 2), conv_bn_relu(w1, w1))
            self.s4 = nn.Sequential(conv_bn_relu(w1, w2, 2), Residual(w2))
            self.s8 = nn.Sequential(conv_bn_relu(w2, w3, 2), Residual(w3))
            self.s16 = nn.Sequential(conv_bn_relu(w3, w4, 2), Residual(w4, dilation=2))
        else:  # pretrained weights are loaded by init_weights (training); a checkpoint holds them afterwards
            self.encoder = EfficientNetLite0Encoder(levels=4)
        self.s16b = nn.Sequential(conv_bn_relu(w4 + e, w4), Residual(w4, dilation=4))
        self.up8 = nn.Sequential(conv_bn_relu(w4 + w3, d8), Residual(d8))
        self.up4 = nn.Sequential(conv_bn_relu(d8 + w2, d4), Residual(d4))
        C, J = cfg.num_classes, cfg.num_keypoints
        self.fg_head = nn.Sequential(conv_bn_relu(d4 + e, d4), nn.Conv2d(d4, C, 1))
        self.kp_head = nn.Sequential(conv_bn_relu(d4 + e, d4), nn.Conv2d(d4, 3 * J * C, 1))
        if cfg.dense:
            self.xyz_head = nn.Sequential(conv_bn_relu(d4 + e, d4), Residual(d4), nn.Conv2d(d4, 4 * cfg.hypotheses * C, 1))
        self.register_buffer("mean", torch.tensor(self.MEAN).view(1, 3, 1, 1), persistent=False)
        self.register_buffer("std", torch.tensor(self.STD).view(1, 3, 1, 1), persistent=False)

    def init_weights(self, generator: torch.Generator) -> None:
        """Deterministic initialisation from ``generator`` (Kaiming convolutions, small heads); a pretrained
        encoder is then filled with its ImageNet weights (bit for bit)."""
        init_conv_weights(self, generator)
        if self.cfg.backbone == "efficientnet-lite0":
            load_imagenet_weights(self.encoder)
        heads = [self.fg_head[-1], self.kp_head[-1]] + ([self.xyz_head[-1]] if self.cfg.dense else [])
        for head in heads:
            nn.init.normal_(head.weight, std=0.01, generator=generator)
            nn.init.zeros_(head.bias)

    def forward(self, x: torch.Tensor) -> dict[str, torch.Tensor]:
        if self.cfg.backbone == "plain":
            f4 = self.s4(self.stem((x - self.mean) / self.std))
            f8 = self.s8(f4)
            f16 = self.s16(f8)
        else:  # the encoder normalises its input as its weights were trained
            _, f4, f8, f16 = self.encoder(x)
        f16 = self.s16b(self._with_coords(f16))
        u8 = self.up8(torch.cat([F.interpolate(f16, size=f8.shape[-2:], mode="bilinear", align_corners=False), f8], 1))
        u4 = self._with_coords(self.up4(torch.cat([F.interpolate(u8, size=f4.shape[-2:], mode="bilinear",
                                                                 align_corners=False), f4], 1)))
        out = {"fg": self.fg_head(u4), "kp": self.kp_head(u4)}
        if self.cfg.dense:
            out["xyz"] = self.xyz_head(u4)
        return out

    def _with_coords(self, f: torch.Tensor) -> torch.Tensor:
        """``f`` with two more channels, the x and y of each cell's centre in [-1, 1] (when ``cfg.coords``)."""
        if not self.cfg.coords:
            return f
        B, _, h, w = f.shape
        ys = torch.linspace(-1.0, 1.0, h, device=f.device, dtype=f.dtype).view(1, 1, h, 1).expand(B, 1, h, w)
        xs = torch.linspace(-1.0, 1.0, w, device=f.device, dtype=f.dtype).view(1, 1, 1, w).expand(B, 1, h, w)
        return torch.cat([f, xs, ys], 1)


def select_class(out: dict[str, torch.Tensor], labels: torch.Tensor, num_keypoints: int
                 ) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """``(fg (B, h, w), offsets (B, J, 2, h, w), conf_logit (B, J, h, w))`` of each crop's class
    (``labels`` (B,) 1..C)."""
    B, _, h, w = out["fg"].shape
    J = num_keypoints
    idx = (labels.to(out["fg"].device).long() - 1).clamp_min(0)
    fg = out["fg"][torch.arange(B, device=idx.device), idx]
    kp = out["kp"].reshape(B, -1, 3 * J, h, w)[torch.arange(B, device=idx.device), idx]
    return fg, kp[:, :2 * J].reshape(B, J, 2, h, w), kp[:, 2 * J:]


def crop_targets(batch: dict[str, torch.Tensor], grid: tuple[int, int], stride: int, offset_scale: float,
                 min_coverage: float = 0.3) -> tuple[torch.Tensor, torch.Tensor]:
    """``(fg cells (B, h, w) bool, offsets (B, J, 2, h, w))``: a cell is object when the target's visible mask
    covers at least ``min_coverage`` of it; offsets from every cell centre to the crop keypoints, in units of
    ``offset_scale`` pixels."""
    h, w = grid
    m = batch["fg"].to(torch.float32)[:, None]
    cov = F.avg_pool2d(m, stride)[:, 0]
    centers = cell_centers(h, w, stride, m.device)  # (2, h, w)
    kp = batch["keypoints_2d"].to(device=m.device, dtype=torch.float32)  # (B, J, 2)
    off = (kp[:, :, :, None, None] - centers[None, None]) / offset_scale
    return cov >= min_coverage, off


def select_class_xyz(xyz: torch.Tensor, labels: torch.Tensor, hypotheses: int = 1
                     ) -> tuple[torch.Tensor, torch.Tensor]:
    """``(coords (B, H, 3, h, w), conf_logit (B, H, h, w))`` of each crop's class from the ``xyz`` output
    (B, 4 H C, h, w) (``labels`` (B,) 1..C, ``H`` hypotheses)."""
    B, _, h, w = xyz.shape
    idx = (labels.to(xyz.device).long() - 1).clamp_min(0)
    sel = xyz.reshape(B, -1, int(hypotheses), 4, h, w)[torch.arange(B, device=xyz.device), idx]
    return sel[:, :, :3], sel[:, :, 3]


#: Weight of the losing hypotheses in the relaxed winner-takes-all loss (keeps every hypothesis learning).
WTA_RELAX = 0.05


def xyz_loss(xyz: torch.Tensor, batch: dict[str, torch.Tensor], cfg: CropNetConfig) -> torch.Tensor:
    """The object-coordinate loss ``c |g - e|_1 - log c`` (coordinates in units of the class's ``xyz_scale``,
    ``c = softplus(z)``) averaged over each crop's cells with a target (``batch["xyz_valid"]``); with several
    hypotheses the best one of each crop counts (relaxed winner-takes-all: the others with weight
    :data:`WTA_RELAX` / (H - 1)); mean over the crops with targets."""
    H = int(cfg.hypotheses)
    e, z = select_class_xyz(xyz, batch["labels"], H)
    valid = batch["xyz_valid"].to(e.device)
    n = valid.flatten(1).sum(1)
    has = n > 0
    if not bool(has.any()):
        return e.sum() * 0.0 + z.sum() * 0.0
    scale = torch.as_tensor(cfg.xyz_scale, dtype=e.dtype, device=e.device)
    idx = (batch["labels"].to(e.device).long() - 1).clamp_min(0)
    g = batch["xyz"].to(device=e.device, dtype=e.dtype) / scale[idx].view(-1, 1, 1, 1)
    err = (g[:, None] - e).abs().sum(2)  # (B, H, h, w)
    c = confidence(z).clamp(1e-6, C_MAX)
    cell = (c * err - torch.log(c)) * valid[:, None].to(e.dtype)
    per = cell.flatten(2).sum(2)[has] / n[has, None].to(e.dtype)  # (B', H)
    if H == 1:
        return per[:, 0].mean()
    best = per.min(1).values
    return ((1.0 - WTA_RELAX) * best + WTA_RELAX * (per.sum(1) - best) / (H - 1)).mean()


def crop_loss(out: dict[str, torch.Tensor], batch: dict[str, torch.Tensor], cfg: CropNetConfig,
              fg_weight: float = 1.0, xyz_weight: float = 1.0, kp_weight: float = 1.0) -> dict[str, torch.Tensor]:
    """``{"loss", "fg", "kp"[, "xyz"]}``: binary cross-entropy of the class's mask logits (positives weighted to
    half the total) plus ``kp_weight`` times the keypoint loss ``sum_j c_j |g_j - e_j|_1 - log c_j`` averaged over
    object cells, plus, for a dense network, ``xyz_weight`` times :func:`xyz_loss`."""
    fg_logit, offsets, conf_logit = select_class(out, batch["labels"], cfg.num_keypoints)
    fg, g = crop_targets(batch, tuple(fg_logit.shape[-2:]), cfg.stride, cfg.offset_scale)
    pos = fg.to(fg_logit.dtype)
    npos = pos.sum().clamp_min(1.0)
    nneg = (1.0 - pos).sum().clamp_min(1.0)
    wts = pos * (0.5 / npos) + (1.0 - pos) * (0.5 / nneg)
    lfg = (F.binary_cross_entropy_with_logits(fg_logit, pos, reduction="none") * wts).sum()
    if bool(fg.any()):
        e = offsets.permute(0, 3, 4, 1, 2)[fg]  # (M, J, 2)
        t = g.permute(0, 3, 4, 1, 2)[fg]
        c = confidence(conf_logit.permute(0, 2, 3, 1)[fg]).clamp(1e-6, C_MAX)
        lkp = (c * (t - e).abs().sum(-1) - torch.log(c)).sum(-1).mean()
    else:
        lkp = offsets.sum() * 0.0 + conf_logit.sum() * 0.0
    res = {"loss": fg_weight * lfg + kp_weight * lkp, "fg": lfg.detach(), "kp": lkp.detach()}
    if cfg.dense:
        lxyz = xyz_loss(out["xyz"], batch, cfg)
        res["loss"] = res["loss"] + xyz_weight * lxyz
        res["xyz"] = lxyz.detach()
    return res
