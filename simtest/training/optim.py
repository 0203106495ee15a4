"""The optimiser of every training run (torch imported lazily): AdamW with the pretrained encoder's learning-rate
scale or frozen encoder, the warm-up + cosine learning-rate schedule per step, one clipped step, and the training
mode with the encoder's batch norms optionally frozen."""

from __future__ import annotations

import math
from typing import Any

__all__ = ["lr_at", "make_optimizer", "set_lr", "optimizer_step", "train_mode"]


def lr_at(step: int, total: int, peak: float) -> float:
    """Learning rate at optimisation step ``step`` of ``total``: linear warm-up over 3 %, then cosine decay to
    2 % of ``peak``."""
    warm = max(1, int(0.03 * total))
    if step < warm:
        return peak * (step + 1) / warm
    p = min(1.0, (step - warm) / max(1, total - warm))
    return peak * (0.02 + 0.98 * 0.5 * (1.0 + math.cos(math.pi * p)))


def optimizer_step(net: Any, opt: Any, losses: dict[str, Any], sums: dict[str, float]) -> None:
    """Back-propagate ``losses["loss"]``, clip the gradient norm at 10, step ``opt``, and add every loss named
    in ``sums`` to it."""
    import torch

    opt.zero_grad(set_to_none=True)
    losses["loss"].backward()
    torch.nn.utils.clip_grad_norm_(net.parameters(), 10.0)
    opt.step()
    for k in sums:
        sums[k] += float(losses[k].detach())


def make_optimizer(net: Any, lr: float, weight_decay: float, encoder_lr_scale: float = 1.0) -> Any:
    """AdamW over ``net``'s parameters; a pretrained encoder (``net.encoder``) learns at ``encoder_lr_scale``
    times the rate of the rest (its group carries ``lr_scale``, see :func:`set_lr`), and with 0 it is frozen
    (no gradient, not in the optimizer): the ImageNet features then reach the real images unchanged, which is
    what transfers from renders to photographs (Hinterstoisser et al., 2018)."""
    import torch

    enc = getattr(net, "encoder", None)
    scale = float(encoder_lr_scale)
    if enc is None or scale == 1.0:
        return torch.optim.AdamW(net.parameters(), lr=lr, weight_decay=weight_decay)
    enc_ids = {id(p) for p in enc.parameters()}
    rest = [p for p in net.parameters() if id(p) not in enc_ids]
    groups = [{"params": rest, "lr_scale": 1.0}]
    if scale > 0:
        groups.append({"params": list(enc.parameters()), "lr_scale": scale})
    else:
        for p in enc.parameters():
            p.requires_grad_(False)
    return torch.optim.AdamW(groups, lr=lr, weight_decay=weight_decay)


def set_lr(opt: Any, lr: float) -> None:
    """Set every parameter group of ``opt`` to ``lr`` times its ``lr_scale`` (1 when absent)."""
    for g in opt.param_groups:
        g["lr"] = lr * g.get("lr_scale", 1.0)


def train_mode(net: Any, freeze_encoder_bn: bool = False) -> None:
    """``net.train()``; with ``freeze_encoder_bn`` the batch norms of a pretrained encoder keep normalising with
    their ImageNet statistics (eval mode), so small batches of renders do not re-centre the features."""
    from torch import nn

    net.train()
    enc = getattr(net, "encoder", None)
    if freeze_encoder_bn and enc is not None:
        for m in enc.modules():
            if isinstance(m, nn.BatchNorm2d):
                m.eval()
