"""Seeding: one seed in, independent child generators out.

No global RNG is used anywhere in simtest. A run takes one integer seed; :func:`spawn` derives one
``SeedSequence`` child per scene / episode, keyed by the index, so the stream of scene ``i`` never depends on
how many scenes ran before it or on how many workers share the work.
"""

from __future__ import annotations

import numpy as np

__all__ = ["root_sequence", "child_sequence", "child_rng"]


def root_sequence(seed: int | None) -> np.random.SeedSequence:
    """The root ``SeedSequence`` of a run.

    Args:
        seed: Non-negative integer seed. ``None`` draws fresh OS entropy (the resulting entropy is available
            as ``.entropy`` and should be recorded so the run can be repeated).

    Raises:
        ValueError: If ``seed`` is negative or not an integer.
    """
    if seed is not None:
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)):
            raise ValueError(f"seed must be a non-negative integer or None, got {seed!r}")
        if seed < 0:
            raise ValueError(f"seed must be a non-negative integer or None, got {seed!r}")
        return np.random.SeedSequence(int(seed))
    return np.random.SeedSequence()


def child_sequence(seed: int | None, *key: int) -> np.random.SeedSequence:
    """The child ``SeedSequence`` at ``key`` below the root of ``seed``.

    ``child_sequence(s, i)`` equals ``root_sequence(s).spawn(i + 1)[i]`` but is computed directly, so a worker
    can derive scene ``i`` without spawning ``0..i-1``. Nested keys (``scene, attempt``) give independent
    streams for retries.
    """
    root = root_sequence(seed)
    return np.random.SeedSequence(root.entropy, spawn_key=tuple(int(k) for k in key))


def child_rng(seed: int | None, *key: int) -> np.random.Generator:
    """A ``numpy.random.Generator`` for the child at ``key`` (see :func:`child_sequence`)."""
    return np.random.default_rng(child_sequence(seed, *key))
