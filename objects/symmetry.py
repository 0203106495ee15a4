"""Symmetry transforms in the BOP toolkit's form (``misc.get_symmetry_transformations``), metres."""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from simtest.geometry import rotation_about

__all__ = ["symmetry_transforms", "discrete_rotations_z", "MAX_SYM_DISC_STEP"]

#: BOP toolkit default: a continuous symmetry is discretised into ``ceil(pi / 0.01) = 315`` rotations.
MAX_SYM_DISC_STEP = 0.01


def symmetry_transforms(discrete: Sequence[np.ndarray], continuous: Sequence, max_step: float = MAX_SYM_DISC_STEP
                        ) -> np.ndarray:
    """All symmetry transforms (S, 4, 4), identity first.

    Follows the BOP toolkit: the identity, every discrete symmetry, and for each continuous symmetry
    ``n = ceil(pi / max_step)`` rotations about its axis at angles ``2 pi k / n`` through its offset; then the
    combinations ``R = R_c R_d``, ``t = R_c t_d + t_c``.

    Args:
        discrete: 4x4 transforms (translation in metres), identity excluded.
        continuous: Objects with ``axis`` and ``offset`` (metres) attributes.
        max_step: ``max_sym_disc_step`` of the BOP toolkit.
    """
    disc = [np.eye(4)] + [np.asarray(s, dtype=np.float64).reshape(4, 4) for s in discrete]
    cont = [np.eye(4)]
    for sym in continuous:
        axis = np.asarray(sym.axis, dtype=np.float64)
        offset = np.asarray(sym.offset, dtype=np.float64)
        n = int(np.ceil(np.pi / max_step))
        for k in range(1, n):
            R = rotation_about(axis, 2.0 * np.pi * k / n)
            T = np.eye(4)
            T[:3, :3] = R
            T[:3, 3] = -R @ offset + offset
            cont.append(T)
    out = []
    for Tc in cont:
        for Td in disc:
            T = np.eye(4)
            T[:3, :3] = Tc[:3, :3] @ Td[:3, :3]
            T[:3, 3] = Tc[:3, :3] @ Td[:3, 3] + Tc[:3, 3]
            out.append(T)
    return np.stack(out)


def discrete_rotations_z(n: int) -> list[np.ndarray]:
    """The ``n - 1`` non-identity rotations by ``2 pi k / n`` about the model z axis, as 4x4 matrices."""
    out = []
    for k in range(1, n):
        T = np.eye(4)
        T[:3, :3] = rotation_about(np.array([0.0, 0.0, 1.0]), 2.0 * np.pi * k / n)
        out.append(T)
    return out
