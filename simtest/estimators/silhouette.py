"""Translation refinement by silhouette alignment: move a pose estimate so its rendered silhouette fits a mask.

An RGB-only estimator that solves PnP from predicted 2D-3D correspondences recovers the rotation and the
image position of an object well, its depth worse: a few percent of error along the ray shifts every model
point by that fraction of the distance, more than the 10 % of the diameter ADD allows for small objects. The
object's outline pins its depth: at 1 m, 1 % farther shrinks a 100-pixel silhouette by a pixel. Here the
translation ``t`` is searched (image shift ``du, dv`` of the projected origin and a depth factor ``s``), and with
``step_deg > 0`` three small camera-frame rotations about the object's origin too, to maximise the soft intersection over union between the model's exact silhouette
(:func:`simtest.render.silhouette.object_silhouette`, the annotator's rasterizer) and a predicted mask
probability, counted only where the mask can be trusted: inside the image and outside the masks of the
other objects found (which may hide part of this one). A pattern search (halving steps) keeps it
deterministic and needs no gradients.

The mask is the object's *visible* region; where something unknown hides part of it, the fit pulls the
silhouette smaller (farther). ``max_scale`` bounds the depth change, and the refined translation is kept only
if it raises the IoU by ``min_gain``.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from simtest.camera import pinhole_pixels, pinhole_points
from simtest.errors import ConfigError
from simtest.render.silhouette import object_silhouette

__all__ = ["SilhouetteFit", "fit_translation", "soft_iou", "cell_coverage_mask"]


@dataclass(frozen=True)
class SilhouetteFit:
    """Result of :func:`fit_translation`: the translation (metres, camera frame), the IoU before and after,
    the depth factor and image shift (pixels of the mask's image) applied, and the silhouette evaluations."""

    t: np.ndarray
    R: np.ndarray
    iou_before: float
    iou_after: float
    scale: float
    shift_px: tuple[float, float]
    evaluations: int
    applied: bool


def soft_iou(sil: np.ndarray, prob: np.ndarray, valid: np.ndarray) -> float:
    """Soft IoU of a bool silhouette and a probability map over the ``valid`` pixels (0 when both are empty)."""
    p = np.where(valid, prob, 0.0)
    return _soft_iou(sil & valid, p, float(p.sum()))


def _soft_iou(sil: np.ndarray, p: np.ndarray, p_sum: float) -> float:
    """:func:`soft_iou` with the silhouette already limited to the valid pixels and ``p`` zero outside them."""
    inter = float(p[sil].sum())
    union = p_sum + float(sil.sum()) - inter
    return inter / union if union > 0 else 0.0


def cell_coverage_mask(sil: np.ndarray, stride: int, min_coverage: float) -> np.ndarray:
    """(H, W) bool: the pixels at which a ``stride`` x ``stride`` cell centred there would be covered by
    ``sil`` to at least ``min_coverage``, the rule that makes a network's object cells from a mask. A mask
    network trained on such cells predicts this outline (grown by about ``(0.5 - min_coverage) stride`` pixels),
    not the silhouette itself."""
    k = np.ones(int(stride) + 1, np.float32)
    k[[0, -1]] = 0.5
    k /= float(stride)
    cov = cv2.sepFilter2D(np.asarray(sil, np.float32), -1, k, k, borderType=cv2.BORDER_CONSTANT)
    return cov >= float(min_coverage) - 1e-6


def fit_translation(obj, R: np.ndarray, t: np.ndarray, K: np.ndarray, prob: np.ndarray, valid: np.ndarray,
                    max_scale: float = 0.15, cells: tuple[int, float] | None = None, min_gain: float = 0.0, step_px: float = 2.0, step_scale: float = 0.02,
                    min_step_px: float = 0.125, step_deg: float = 0.0) -> SilhouetteFit:
    """Refine pose ``(R, t)`` of ``obj`` so its silhouette matches ``prob``: the translation, and with
    ``step_deg > 0`` small rotations as well.

    Args:
        obj: The :class:`~simtest.objects.ObjectModel` (mesh in metres).
        R, t: Pose estimate, model to camera (OpenCV frame), ``t`` in metres.
        K: 3x3 intrinsics of the image ``prob`` lies in (e.g. a crop's ``K' = M K``), pixels.
        prob: (H, W) mask probability in [0, 1] of the object's visible pixels.
        valid: (H, W) bool, the pixels that count (inside the image, not hidden by other objects found).
        max_scale: Largest relative depth change ``|s - 1|``.
        cells: ``(stride, min_coverage)`` when ``prob`` is a cell mask upsampled to pixels (the silhouette is
            then compared through :func:`cell_coverage_mask`); None: ``prob`` is a pixel mask.
        min_gain: Keep the fit only when it raises the IoU by more than this.
        step_px, step_scale: First steps of the pattern search (pixels, relative depth).
        min_step_px: The search stops when the pixel step falls below this (the other steps shrink with it).
        step_deg: First rotation step, degrees (0: the rotation stays).

    Returns:
        A :class:`SilhouetteFit`; ``R`` and ``t`` are the input's when the fit was not applied.

    Raises:
        ConfigError: Mismatched shapes or bad bounds.
    """
    prob = np.asarray(prob, np.float64)
    valid = np.asarray(valid, bool)
    if prob.ndim != 2 or prob.shape != valid.shape:
        raise ConfigError(f"fit_translation: prob and valid must be the same (H, W), got {prob.shape} and "
                          f"{valid.shape}")
    if not 0.0 < float(max_scale) < 1.0 or not float(step_px) > 0 or not float(min_step_px) > 0:
        raise ConfigError(f"fit_translation: need 0 < max_scale < 1 and positive steps, got max_scale="
                          f"{max_scale!r}, step_px={step_px!r}, min_step_px={min_step_px!r}")
    K = np.asarray(K, np.float64)
    R = np.asarray(R, np.float64)
    t = np.asarray(t, np.float64).reshape(3)
    H, W = prob.shape
    p_valid = np.where(valid, prob, 0.0)  # constant over the search
    p_sum = float(p_valid.sum())
    u0, v0 = pinhole_pixels(K, t)
    n_eval = 0

    def trans(x: np.ndarray) -> np.ndarray:
        return pinhole_points(K, u0 + x[0], v0 + x[1], t[2] * float(np.exp(x[2])))

    def rot(x: np.ndarray) -> np.ndarray:
        if not x[3:].any():
            return R
        return cv2.Rodrigues(x[3:].reshape(3, 1))[0] @ R

    def score(x: np.ndarray) -> float:
        nonlocal n_eval
        n_eval += 1
        sil = object_silhouette(obj, rot(x), trans(x), K, W, H)
        if cells is not None:
            sil = cell_coverage_mask(sil, *cells)
        return _soft_iou(sil & valid, p_valid, p_sum)

    x = np.zeros(6)
    best = before = score(x)
    lim = float(np.log1p(max_scale)), float(-np.log1p(-max_scale))
    steps = np.array([step_px, step_px, np.log1p(step_scale)] + [np.radians(step_deg)] * 3)
    order = (2, 0, 1, 3, 4, 5) if step_deg > 0 else (2, 0, 1)
    while steps[0] >= min_step_px:
        moved = False
        for k in order:
            for sgn in (1.0, -1.0):
                y = x.copy()
                y[k] += sgn * steps[k]
                if not -lim[1] <= y[2] <= lim[0]:
                    continue
                f = score(y)
                if f > best:
                    x, best, moved = y, f, True
                    break
        if not moved:
            steps = steps / 2.0
    applied = best > before + float(min_gain)
    return SilhouetteFit(t=trans(x) if applied else t.copy(), R=rot(x) if applied else R.copy(), iou_before=before, iou_after=best,
                         scale=float(np.exp(x[2])) if applied else 1.0,
                         shift_px=(float(x[0]), float(x[1])) if applied else (0.0, 0.0), evaluations=n_eval,
                         applied=applied)
