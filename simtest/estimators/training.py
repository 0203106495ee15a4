"""What the learned estimators' trainers share (torch imported lazily): the result record, the per-epoch
shuffling generator, the learning-rate schedule, the epoch's data loader and stride-16 padding.

Every random choice derives from the run's seed and the epoch (``SeedSequence(seed, spawn_key=(epoch, ...))``),
so a resumed run shuffles exactly as an uninterrupted one.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

__all__ = ["TrainResult", "epoch_generator", "lr_at", "epoch_loader", "pad16"]


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
