"""What the learned estimators' trainers share (torch imported lazily): the result record, the per-epoch
shuffling generator, the learning-rate schedule, the epoch's data loader and stride-16 padding.

Every random choice derives from the run's seed and the epoch (``SeedSequence(seed, spawn_key=(epoch, ...))``),
so a resumed run shuffles exactly as an uninterrupted one.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from simtest.errors import ConfigError

__all__ = ["TrainResult", "export_beside", "epoch_generator", "lr_at", "epoch_loader", "pad16", "optimizer_step", "check_device",
           "check_settings", "settings_dict", "init_conv_weights", "make_optimizer", "set_lr", "train_mode",
           "check_encoder_settings"]


@dataclass
class TrainResult:
    """What a run produced: checkpoint paths, per-epoch history (losses, validation scores), wall time of this
    call (s)."""

    model_path: Path
    last_path: Path
    best_path: Path | None
    history: list[dict[str, Any]] = field(default_factory=list)
    seconds: float = 0.0


def epoch_generator(seed: int, epoch: int):
    """The torch generator that shuffles epoch ``epoch`` of a run seeded ``seed``."""
    import torch

    state = np.random.SeedSequence(int(seed), spawn_key=(int(epoch), 0x5EED)).generate_state(2, np.uint64)
    return torch.Generator().manual_seed(int(state[0] >> np.uint64(1)))


def lr_at(step: int, total: int, peak: float) -> float:
    """Learning rate at optimisation step ``step`` of ``total``: linear warm-up over 3 %, then cosine decay to
    2 % of ``peak``."""
    warm = max(1, int(0.03 * total))
    if step < warm:
        return peak * (step + 1) / warm
    p = min(1.0, (step - warm) / max(1, total - warm))
    return peak * (0.02 + 0.98 * 0.5 * (1.0 + math.cos(math.pi * p)))


def epoch_loader(dataset, batch_size: int, workers: int, seed: int, epoch: int):
    """The shuffled DataLoader of epoch ``epoch`` (the dataset's per-sample corruptions are seeded by it too)."""
    from torch.utils.data import DataLoader

    from simtest.data import collate

    dataset.set_epoch(epoch)
    return DataLoader(dataset, batch_size=batch_size, shuffle=True, drop_last=len(dataset) >= batch_size,
                      num_workers=int(workers), collate_fn=collate, generator=epoch_generator(seed, epoch))


def pad16(x):
    """``x`` (..., H, W) zero-padded at the bottom and right to multiples of 16 pixels."""
    from torch.nn import functional as F

    H, W = x.shape[-2:]
    return F.pad(x, (0, (-W) % 16, 0, (-H) % 16))


def optimizer_step(net, opt, losses: dict, sums: dict[str, float]) -> None:
    """Back-propagate ``losses["loss"]``, clip the gradient norm at 10, step ``opt``, and add every loss named
    in ``sums`` to it."""
    import torch

    opt.zero_grad(set_to_none=True)
    losses["loss"].backward()
    torch.nn.utils.clip_grad_norm_(net.parameters(), 10.0)
    opt.step()
    for k in sums:
        sums[k] += float(losses[k].detach())


def make_optimizer(net, lr: float, weight_decay: float, encoder_lr_scale: float = 1.0):
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


def set_lr(opt, lr: float) -> None:
    """Set every parameter group of ``opt`` to ``lr`` times its ``lr_scale`` (1 when absent)."""
    for g in opt.param_groups:
        g["lr"] = lr * g.get("lr_scale", 1.0)


def train_mode(net, freeze_encoder_bn: bool = False) -> None:
    """``net.train()``; with ``freeze_encoder_bn`` the batch norms of a pretrained encoder keep normalising with
    their ImageNet statistics (eval mode), so small batches of renders do not re-centre the features."""
    from torch import nn

    net.train()
    enc = getattr(net, "encoder", None)
    if freeze_encoder_bn and enc is not None:
        for m in enc.modules():
            if isinstance(m, nn.BatchNorm2d):
                m.eval()


def check_encoder_settings(cfg: Any, who: str) -> None:
    """``encoder_lr_scale`` in [0, 1] and ``freeze_encoder_bn`` only with a pretrained backbone."""
    scale, frozen = float(getattr(cfg, "encoder_lr_scale", 1.0)), bool(getattr(cfg, "freeze_encoder_bn", False))
    if not 0.0 <= scale <= 1.0:
        raise ConfigError(f"{who}: encoder_lr_scale must be in [0, 1], got {scale!r}")
    if (scale != 1.0 or frozen) and getattr(cfg, "backbone", "plain") == "plain":
        raise ConfigError(f"{who}: encoder_lr_scale and freeze_encoder_bn apply to a pretrained encoder; "
                          "use backbone efficientnet-lite0 (the plain encoder trains from scratch)")


def check_device(device: str, who: str) -> None:
    """Raise :class:`ConfigError` (naming ``who``) unless ``device`` is ``cpu``, ``cuda`` or ``cuda:N``."""
    if device not in ("cpu", "cuda") and not str(device).startswith("cuda:"):
        raise ConfigError(f"{who}: device must be cpu or cuda[:N], got {device!r}")


def check_settings(cfg: Any, who: str) -> None:
    """The checks every training config shares: ``epochs``, ``batch_size`` >= 1, ``workers`` >= 0, ``lr`` > 0,
    ``augment_p`` in [0, 1], ``seed`` a non-negative integer, a known ``device``; errors name ``who``."""
    for name, lo in (("epochs", 1), ("batch_size", 1), ("workers", 0)):
        if int(getattr(cfg, name)) < lo:
            raise ConfigError(f"{who}: {name} must be >= {lo}, got {getattr(cfg, name)!r}")
    if not cfg.lr > 0:
        raise ConfigError(f"{who}: lr must be > 0, got {cfg.lr!r}")
    if not 0.0 <= cfg.augment_p <= 1.0:
        raise ConfigError(f"{who}: augment_p must be in [0, 1], got {cfg.augment_p!r}")
    if cfg.seed is None or int(cfg.seed) < 0:
        raise ConfigError(f"{who}: seed must be a non-negative integer, got {cfg.seed!r}")
    check_device(cfg.device, who)


def settings_dict(cfg: Any) -> dict[str, Any]:
    """A training config as plain JSON-able data (tuples as lists), as checkpoints record it."""
    d = asdict(cfg)
    return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}


def init_conv_weights(net, generator) -> None:
    """Deterministic initialisation from ``generator``: Kaiming-normal convolutions (fan out) with zero bias,
    batch norms at identity."""
    from torch import nn

    for m in net.modules():
        if isinstance(m, nn.Conv2d):
            nn.init.kaiming_normal_(m.weight, mode="fan_out", nonlinearity="relu", generator=generator)
            if m.bias is not None:
                nn.init.zeros_(m.bias)
        elif isinstance(m, nn.BatchNorm2d):
            nn.init.ones_(m.weight)
            nn.init.zeros_(m.bias)


def export_beside(*checkpoints: Path) -> list[Path]:
    """The ONNX file of each existing checkpoint, written beside it (``model.pt`` -> ``model.onnx``), so the run
    is evaluated without torch (:mod:`simtest.estimators.onnx_net`). Without the exporter's packages (onnx,
    onnxscript) the checkpoints stay usable with torch and a warning names the command that converts them."""
    import logging

    from simtest.estimators.onnx_export import export_checkpoint

    out = []
    for ckpt in checkpoints:
        if ckpt is None or not Path(ckpt).is_file():
            continue
        try:
            out.append(export_checkpoint(ckpt))
        except ConfigError as exc:
            logging.getLogger(__name__).warning("no ONNX file for %s (%s); convert it later with: simtest export %s",
                                                ckpt, exc, ckpt)
    return out
