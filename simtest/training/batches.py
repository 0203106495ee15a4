"""The batches of a training epoch (torch imported lazily): the seeded shuffling generator, the epoch's data
loader and stride-16 padding.

Every random choice derives from the run's seed and the epoch (``SeedSequence(seed, spawn_key=(epoch, ...))``),
so a resumed run shuffles exactly as an uninterrupted one.
"""

from __future__ import annotations

from typing import Any, Callable

import numpy as np

from simtest.data import collate as collate_samples

__all__ = ["epoch_generator", "epoch_loader", "pad16"]


def epoch_generator(seed: int, epoch: int) -> Any:
    """The torch generator that shuffles epoch ``epoch`` of a run seeded ``seed``."""
    import torch

    state = np.random.SeedSequence(int(seed), spawn_key=(int(epoch), 0x5EED)).generate_state(2, np.uint64)
    return torch.Generator().manual_seed(int(state[0] >> np.uint64(1)))


def epoch_loader(dataset: Any, batch_size: int, workers: int, seed: int, epoch: int,
                 collate: Callable[[list], Any] | None = None) -> Any:
    """The shuffled DataLoader of epoch ``epoch`` (the dataset's per-sample corruptions are seeded by it too);
    ``collate`` joins samples into a batch (None: :func:`simtest.data.collate`)."""
    from torch.utils.data import DataLoader

    dataset.set_epoch(epoch)
    return DataLoader(dataset, batch_size=batch_size, shuffle=True, drop_last=len(dataset) >= batch_size,
                      num_workers=int(workers), collate_fn=collate_samples if collate is None else collate,
                      generator=epoch_generator(seed, epoch))


def pad16(x: Any) -> Any:
    """``x`` (..., H, W) zero-padded at the bottom and right to multiples of 16 pixels."""
    from torch.nn import functional as F

    H, W = x.shape[-2:]
    return F.pad(x, (0, (-W) % 16, 0, (-H) % 16))
