"""Tracking metrics: per-frame errors of a pose track and their summaries (category-level tracking protocol).

Notation: per frame ``k`` of one track (one object instance followed through one sequence), the ground-truth
pose ``(R_g, t_g)`` and the estimate ``(R_e, t_e)`` map model points (metres) into the camera frame; a frame
without an estimate is a *miss*.

* **Rotation error** ``R_err`` (degrees): ``min_S arccos(clip((trace(R_e (R_g R_S)^T) - 1) / 2, -1, 1))`` over
  the object's symmetry set ``S`` (identity included; :func:`simtest.metrics.pose.re_sym`).
* **Translation error** ``T_err`` (centimetres): ``100 ||t_e - t_g||``.
* **3D IoU** of the model's bounding box ``B = [lo, hi]`` (model frame) posed by the estimate and by the ground
  truth: ``IoU = vol(B_e ∩ B_g) / (vol(B_e) + vol(B_g) - vol(B_e ∩ B_g))``, computed exactly
  (:func:`simtest.metrics.nocs.iou_3d`: the intersection of two convex boxes is the convex hull of the corners
  of each inside the other and the crossings of each one's edges with the other's faces). For a symmetric
  object the largest IoU over the symmetry set (``B_g`` posed by ``T_g S``) counts. A miss scores 0.
* **IoU25 / IoU50 / IoU75**: fraction of frames with ``IoU >= 0.25 / 0.50 / 0.75``.
* **n deg m cm** (5°2cm, 5°5cm, 10°2cm, 10°5cm): fraction of frames with ``R_err <= n`` and ``T_err <= m``
  (inclusive); a miss fails.
* **Loss**: a track is lost at its first frame ``k*`` that is a miss or has ``R_err > 10°`` or
  ``T_err > 5 cm`` (:data:`LOSS_DEG`, :data:`LOSS_CM`: the frame fails 10°5cm); the *tracked fraction* is
  ``k* / n`` for a track of ``n`` frames (1 when never lost).

Pure numpy (the exact box intersection uses ``scipy.spatial.ConvexHull`` through :mod:`simtest.metrics.nocs`).
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from typing import Any

import numpy as np

from simtest.errors import ConfigError
from simtest.geometry import as_matrix
from simtest.metrics.nocs import iou_3d, iou_accuracy, n_deg_m_cm_accuracy

__all__ = ["LOSS_DEG", "LOSS_CM", "box_iou", "first_loss", "tracked_fraction", "summarize_frames"]

#: A frame whose rotation error exceeds this (degrees) counts as lost.
LOSS_DEG = 10.0
#: A frame whose translation error exceeds this (centimetres) counts as lost.
LOSS_CM = 5.0


def _bounds(bounds: Any) -> tuple[np.ndarray, np.ndarray]:
    b = np.asarray(bounds, dtype=np.float64)
    if b.shape != (2, 3) or not np.all(b[1] > b[0]):
        raise ConfigError(f"bounds must be [[xmin, ymin, zmin], [xmax, ymax, zmax]] (metres, max > min), got "
                          f"{np.asarray(bounds).tolist()!r}")
    return b[0], b[1]


def box_iou(R_e: Any, t_e: Any, R_g: Any, t_g: Any, bounds: Any, syms: Any = None) -> float:
    """Exact 3D IoU of the model's bounding box posed by the estimate and by the ground truth (module doc).

    Args:
        R_e, t_e: Estimated pose (model -> camera; metres).
        R_g, t_g: Ground-truth pose.
        bounds: (2, 3) model-frame box ``[lo, hi]``, metres (:attr:`ObjectModel.bbox`).
        syms: Optional symmetry transforms (S, 4, 4) of the object (identity included); the largest IoU over
            ``T_g S`` is returned.

    Returns:
        IoU in [0, 1].
    """
    lo, hi = _bounds(bounds)
    centre = np.eye(4)
    centre[:3, 3] = 0.5 * (lo + hi)
    size = hi - lo
    T_e, T_g = as_matrix(np.reshape(R_e, (3, 3)), t_e) @ centre, as_matrix(np.reshape(R_g, (3, 3)), t_g)
    S = np.eye(4)[None] if syms is None else np.asarray(syms, dtype=np.float64)
    if S.ndim != 3 or S.shape[1:] != (4, 4) or len(S) == 0:
        raise ConfigError(f"syms must be (S, 4, 4) symmetry transforms, got shape {S.shape}")
    return max(iou_3d(T_e, T_g @ s @ centre, size, size) for s in S)


def first_loss(re_deg: Sequence[float], te_cm: Sequence[float], matched: Sequence[bool],
               max_deg: float = LOSS_DEG, max_cm: float = LOSS_CM) -> int:
    """Index of a track's first lost frame: a miss, or ``R_err > max_deg`` degrees or ``T_err > max_cm``
    centimetres; the number of frames when it is never lost.

    Args:
        re_deg: Per-frame rotation errors, degrees (ignored on misses).
        te_cm: Per-frame translation errors, centimetres (ignored on misses).
        matched: Per frame, whether there is an estimate.
        max_deg, max_cm: Loss thresholds.
    """
    r = np.asarray(re_deg, dtype=np.float64)
    t = np.asarray(te_cm, dtype=np.float64)
    m = np.asarray(matched, dtype=bool)
    if not (r.shape == t.shape == m.shape) or r.ndim != 1:
        raise ConfigError(f"re_deg, te_cm and matched must be 1-D of equal length, got shapes {r.shape}, "
                          f"{t.shape}, {m.shape}")
    with np.errstate(invalid="ignore"):
        ok = m & (r <= max_deg) & (t <= max_cm)
    bad = np.flatnonzero(~ok)
    return int(bad[0]) if len(bad) else len(ok)


def tracked_fraction(re_deg: Sequence[float], te_cm: Sequence[float], matched: Sequence[bool],
                     max_deg: float = LOSS_DEG, max_cm: float = LOSS_CM) -> float:
    """``first_loss / n``: the fraction of a track's ``n`` frames before its first loss, in [0, 1]."""
    n = len(matched)
    if n == 0:
        raise ConfigError("a track needs at least one frame")
    return first_loss(re_deg, te_cm, matched, max_deg, max_cm) / n


def summarize_frames(frames: Iterable[dict[str, Any]]) -> dict[str, float]:
    """Tracking aggregates pooled over per-frame rows.

    Args:
        frames: Rows with ``matched`` (bool), ``re_deg`` (degrees), ``te_cm`` (centimetres) and ``iou``; a
            miss (``matched`` False) counts as IoU 0 and fails every n deg m cm test.

    Returns:
        ``iou25``, ``iou50``, ``iou75``, ``mean_iou`` (fractions), the n deg m cm accuracies (``"5deg2cm"``
        ...), ``mean_re_deg`` (degrees) and ``mean_te_m`` (metres) over frames with an estimate (NaN when
        none), and ``num_targets`` (frames).
    """
    rows = list(frames)
    if not rows:
        raise ConfigError("no frames to summarize")
    m = np.array([bool(r["matched"]) for r in rows])
    iou = np.where(m, [float(r.get("iou", 0.0)) if r["matched"] else 0.0 for r in rows], 0.0)
    r_deg = np.array([float(r["re_deg"]) if r["matched"] else np.inf for r in rows])
    t_cm = np.array([float(r["te_cm"]) if r["matched"] else np.inf for r in rows])
    out: dict[str, float] = iou_accuracy(iou)
    out["mean_iou"] = float(np.mean(iou))
    out.update(n_deg_m_cm_accuracy(r_deg, t_cm))
    out["mean_re_deg"] = float(np.mean(r_deg[m])) if m.any() else float("nan")
    out["mean_te_m"] = float(np.mean(t_cm[m])) / 100.0 if m.any() else float("nan")
    out["num_targets"] = len(rows)
    return out
