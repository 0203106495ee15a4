"""Targets and losses of the keypoint network (torch).

* Segmentation: class-balanced focal loss over all cells (classes weighted by inverse frequency in the batch).
* Keypoints, on the cells of each visible instance: the KL-derived loss of a Laplace-like predictive
  distribution with learned confidence,

  ``L = sum_j c_j |g_j - e_j|_1 - log c_j``,  with ``c_j = log(1 / (1 - sigmoid(z_j))) = softplus(z_j)``,

  where ``g_j`` and ``e_j`` are the target and predicted offsets of keypoint ``j`` from the cell centre (in
  units of ``offset_scale`` pixels) and ``z_j`` the confidence logit. For a fixed error the loss is smallest at
  ``c_j = 1 / |g_j - e_j|_1``, so the confidence learns to be the inverse expected error.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import torch
from torch.nn import functional as F

from simtest.estimators.keypoints.model import cell_centers

__all__ = ["Targets", "make_targets", "focal_loss", "keypoint_loss", "total_loss", "confidence"]

#: Fraction of a cell an instance's visible mask must cover for the cell to belong to it.
MIN_COVERAGE = 0.3
#: Upper bound of the confidence inside the loss (an error of ``1 / C_MAX`` offset units ~ 0.3 px).
C_MAX = 100.0


def confidence(conf_logit: torch.Tensor) -> torch.Tensor:
    """``c = log(1 / (1 - sigmoid(z))) = softplus(z)`` (computed stably)."""
    return F.softplus(conf_logit)


@dataclass
class Targets:
    """Per-cell targets of a batch.

    Attributes:
        cls: (B, h, w) int64 class per cell (0 = background).
        inst: (B, h, w) int64 index into the batch's instances (-1 = background).
        offsets: (B, J, 2, h, w) float32 keypoint offsets from the cell centres, in offset units (0 off-object).
    """

    cls: torch.Tensor
    inst: torch.Tensor
    offsets: torch.Tensor


def make_targets(batch: dict[str, Any], grid: tuple[int, int], stride: int, offset_scale: float) -> Targets:
    """Cell targets from a collated batch (:func:`simtest.data.collate`).

    A cell belongs to the instance covering most of it if that covers at least :data:`MIN_COVERAGE`.
    """
    h, w = grid
    B = batch["rgb"].shape[0]
    device = batch["rgb"].device
    masks = batch["masks"].to(device=device, dtype=torch.float32)
    N = masks.shape[0]
    J = batch["keypoints_2d"].shape[1] if N else 1
    cls = torch.zeros((B, h, w), dtype=torch.int64, device=device)
    inst = torch.full((B, h, w), -1, dtype=torch.int64, device=device)
    offsets = torch.zeros((B, J, 2, h, w), dtype=torch.float32, device=device)
    if N == 0:
        return Targets(cls, inst, offsets)
    H, W = masks.shape[-2:]
    pad_h, pad_w = h * stride - H, w * stride - W
    cov = F.avg_pool2d(F.pad(masks[:, None], (0, pad_w, 0, pad_h)), stride)[:, 0]  # (N, h, w)
    bidx = batch["batch_index"].to(device)
    centers = cell_centers(h, w, stride, device)  # (2, h, w)
    kp = batch["keypoints_2d"].to(device=device, dtype=torch.float32)  # (N, J, 2)
    for b in range(B):
        ids = torch.nonzero(bidx == b).flatten()
        if len(ids) == 0:
            continue
        c = cov[ids]
        best, arg = c.max(0)
        fg = best >= MIN_COVERAGE
        owner = ids[arg]
        inst[b][fg] = owner[fg]
        cls[b][fg] = batch["labels"].to(device)[owner[fg]]
        # offsets for every cell of its owner (masked later)
        tgt = kp[owner]  # (h, w, J, 2)
        off = (tgt.permute(2, 3, 0, 1) - centers[None]) / offset_scale  # (J, 2, h, w)
        offsets[b] = torch.where(fg[None, None], off, torch.zeros_like(off))
    return Targets(cls, inst, offsets)


def focal_loss(logits: torch.Tensor, target: torch.Tensor, gamma: float = 2.0) -> torch.Tensor:
    """Class-balanced focal loss.

    Args:
        logits: (B, C+1, h, w).
        target: (B, h, w) int64 classes.
        gamma: Focusing exponent.

    Returns:
        Scalar: ``sum(alpha_y (1 - p_y)^gamma (-log p_y)) / sum(alpha_y)`` with ``alpha_c`` the inverse
        frequency of class ``c`` among the batch's cells (classes present only).
    """
    C = logits.shape[1]
    logp = F.log_softmax(logits, 1)
    logp_y = logp.gather(1, target[:, None])[:, 0]
    counts = torch.bincount(target.flatten(), minlength=C).to(logits.dtype)
    alpha = torch.where(counts > 0, counts.sum() / (counts.clamp_min(1) * (counts > 0).sum()), torch.zeros_like(counts))
    a = alpha[target]
    loss = a * (1.0 - logp_y.exp()).pow(gamma) * (-logp_y)
    return loss.sum() / a.sum().clamp_min(1e-6)


def keypoint_loss(offsets: torch.Tensor, conf_logit: torch.Tensor, targets: Targets) -> torch.Tensor:
    """Mean over foreground cells of ``sum_j c_j |g_j - e_j|_1 - log c_j`` (see the module doc)."""
    fg = targets.inst >= 0  # (B, h, w)
    if not bool(fg.any()):
        return offsets.sum() * 0.0 + conf_logit.sum() * 0.0
    e = offsets.permute(0, 3, 4, 1, 2)[fg]  # (M, J, 2)
    g = targets.offsets.permute(0, 3, 4, 1, 2)[fg]
    z = conf_logit.permute(0, 2, 3, 1)[fg]  # (M, J)
    c = confidence(z).clamp(1e-6, C_MAX)
    err = (g - e).abs().sum(-1)
    return (c * err - torch.log(c)).sum(-1).mean()


def total_loss(out: dict[str, torch.Tensor], targets: Targets, seg_weight: float = 2.0) -> dict[str, torch.Tensor]:
    """``{"loss", "seg", "kp"}`` with ``loss = seg_weight * seg + kp``."""
    seg = focal_loss(out["seg"], targets.cls)
    kp = keypoint_loss(out["offsets"], out["conf_logit"], targets)
    return {"loss": seg_weight * seg + kp, "seg": seg.detach(), "kp": kp.detach()}
