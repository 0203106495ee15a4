"""Matching a crop's features against a template bank, and the pose a matched template gives.

Score of template ``j`` for a query crop: the mean, over the template's object cells (weighted by the fraction
of each cell the object covers), of the cosine similarity between the query's and the template's cell
features at the same cell (Nguyen et al., "Templates for 3D object pose estimation revisited", CVPR 2022).
With ``query_mask`` the query's cells are weighted by its own region mask too, so cells of the query's
background or occluders add nothing. With ``hidden`` the query's cells that show something in front of the
object (another object's region) are left out of the score and out of the coverage it is divided by: the score
is then the mean over the template's cells in view, so a template is not marked down for the part an occluder
hides (the coverage counted is at least :data:`MIN_SEEN` of the template's, so that a template hidden almost
whole cannot win on a few cells).
"""

from __future__ import annotations

import numpy as np

from simtest.estimators.templates.bank import TemplateBank

__all__ = ["template_weights", "template_coverage", "match_scores", "template_pose", "MIN_SEEN"]

#: The smallest fraction of a template's coverage a score is divided by when cells are ``hidden``.
MIN_SEEN = 0.5


def template_weights(bank: TemplateBank) -> np.ndarray:
    """(N, C h w) float32: each template's unit features times its cell coverage, divided by the coverage sum,
    so that ``query_flat @ weights.T`` is the score of every template."""
    m = bank.masks.astype(np.float32)
    w = m / np.maximum(m.sum(axis=(1, 2), keepdims=True), 1e-6)
    return (bank.feats.astype(np.float32) * w[:, None]).reshape(len(bank), -1)


def template_coverage(bank: TemplateBank) -> np.ndarray:
    """(N, h w) float32: each template's cell coverage (the fraction of each cell its object covers)."""
    return bank.masks.astype(np.float32).reshape(len(bank), -1)


def match_scores(query: np.ndarray, weights: np.ndarray, query_masks: np.ndarray | None = None,
                 hidden: np.ndarray | None = None, coverage: np.ndarray | None = None) -> np.ndarray:
    """(n, N) scores of ``n`` query crops' unit features (n, C, h, w) against the templates' ``weights``
    (:func:`template_weights`); with ``query_masks`` (n, h, w) in [0, 1] each query cell is weighted by it;
    with ``hidden`` (n, h, w) in [0, 1] (the fraction of each cell something in front covers) and the templates'
    ``coverage`` (:func:`template_coverage`) hidden cells are left out (see the module doc)."""
    q = query if query_masks is None else query * query_masks[:, None]
    if hidden is None or not np.any(hidden):
        return q.reshape(len(q), -1).astype(np.float32) @ weights.T
    if coverage is None:
        raise ValueError("match_scores: hidden cells need the templates' coverage")
    seen = 1.0 - np.clip(np.asarray(hidden, np.float32).reshape(len(q), -1), 0.0, 1.0)
    scores = (q.reshape(len(q), q.shape[1], -1).astype(np.float32) * seen[:, None]).reshape(len(q), -1) @ weights.T
    total = np.maximum(coverage.sum(axis=1), 1e-6)
    return scores / np.maximum((seen @ coverage.T) / total, MIN_SEEN)


def template_pose(bank: TemplateBank, j: int, K_crop: np.ndarray, R_virt: np.ndarray
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Pose ``(R, t)`` (model to real camera, metres) of an object whose crop (intrinsics ``K_crop``, camera
    rotation ``R_virt`` from the real camera) shows template ``j``: the same rotation in the crop's camera, the
    object's centre on the same crop pixel, at the depth that makes it the same size in pixels."""
    Kt, tt = bank.K[j], bank.t[j]
    uv = (Kt @ tt)[:2] / tt[2]
    z = tt[2] * float(K_crop[0, 0]) / float(Kt[0, 0])
    t_c = z * np.linalg.solve(np.asarray(K_crop, np.float64), np.array([uv[0], uv[1], 1.0]))
    return R_virt.T @ bank.R[j], R_virt.T @ t_c
