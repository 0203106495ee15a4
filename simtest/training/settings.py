"""The settings every training run shares: their checks and their record in the checkpoints."""

from __future__ import annotations

from dataclasses import asdict
from typing import Any

from simtest.errors import ConfigError
from simtest.estimators.onnx_net import check_device

__all__ = ["check_settings", "check_encoder_settings", "settings_dict"]


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


def check_encoder_settings(cfg: Any, who: str) -> None:
    """``encoder_lr_scale`` in [0, 1] and ``freeze_encoder_bn`` only with a pretrained backbone."""
    scale, frozen = float(getattr(cfg, "encoder_lr_scale", 1.0)), bool(getattr(cfg, "freeze_encoder_bn", False))
    if not 0.0 <= scale <= 1.0:
        raise ConfigError(f"{who}: encoder_lr_scale must be in [0, 1], got {scale!r}")
    if (scale != 1.0 or frozen) and getattr(cfg, "backbone", "plain") == "plain":
        raise ConfigError(f"{who}: encoder_lr_scale and freeze_encoder_bn apply to a pretrained encoder; "
                          "use backbone efficientnet-lite0 (the plain encoder trains from scratch)")


def settings_dict(cfg: Any) -> dict[str, Any]:
    """A training config as plain JSON-able data (tuples as lists), as checkpoints record it."""
    d = asdict(cfg)
    return {k: list(v) if isinstance(v, tuple) else v for k, v in d.items()}
