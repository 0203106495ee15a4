"""Framing search: the crop's aim, size and roll changed until the templates match it best.

A region's crop is framed by the region's box (:func:`~simtest.estimators.templates.crops.region_crop`), and
the matched template's pose takes its depth from that framing (:func:`~simtest.estimators.templates.match.
template_pose`): a region that is too large, too small or off the object moves the pose in depth and across the
image. The search frees the pose from the region's outline. A framing is a virtual camera aimed at a real pixel
``uv``, rolled by an angle, with a square window of some side around its principal point
(:func:`~simtest.estimators.templates.crops.aimed_crop`). Starting from the region's framing, the search tries
the aim moved by ``±shift`` times the side along each image axis, the side scaled by ``exp(±scale)`` and the
roll turned by ``±roll_deg`` (eight neighbours), encodes the crops, scores each against every template, and
moves to the best neighbour while its best template scores higher than the current framing's; when none does,
every step halves, down to ``min_shift``. The query's cells are not weighted by the region's mask (the
template's own coverage weights them), so the region's outline does not pull the framing back. With ``hidden``
(the pixels of other objects' regions) the crop's cells those cover are left out of the scores
(:func:`~simtest.estimators.templates.match.match_scores`), so that the cells over something in front do not
mark the true framing down (on a render this keeps a partly hidden object from being shrunk into its visible
part; on the real LM-O frames it did not gain, docs/sim2real.md, nineteenth round).
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np

from simtest.estimators.templates.crops import Crop, aimed_crop, mask_in_crop
from simtest.estimators.templates.encoder import FeatureEncoder
from simtest.estimators.templates.match import match_scores

__all__ = ["Framing", "framing_search", "hidden_cells"]

_MOVES = np.concatenate([np.eye(4), -np.eye(4)])


@dataclass(frozen=True)
class Framing:
    """The best framing found: its ``crop``, the best ``template`` index and its ``score``, the query's unit
    features ``query`` (C, h, w), the roll ``roll_rad`` and the number of ``crops`` encoded by the search."""

    crop: Crop
    template: int
    score: float
    query: np.ndarray
    roll_rad: float
    crops: int


def hidden_cells(hidden: np.ndarray | None, K: np.ndarray, crops: list[Crop], cells: tuple[int, int]
                 ) -> np.ndarray | None:
    """(n, h, w) float32: the fraction of each feature cell (``cells`` = (h, w)) of every crop that the real
    image's mask ``hidden`` (H, W) bool covers (None when there is no such mask or it is empty)."""
    if hidden is None or not np.any(hidden):
        return None
    h, w = cells
    return np.stack([cv2.resize(mask_in_crop(hidden, K, c).astype(np.float32), (w, h), interpolation=cv2.INTER_AREA)
                     for c in crops])


def framing_search(rgb: np.ndarray, K: np.ndarray, uv, side: float, roll_rad: float, encoder: FeatureEncoder,
                   weights: np.ndarray, size: int, shift: float = 0.08, scale: float = 0.12,
                   roll_deg: float = 8.0, min_shift: float = 0.01, max_moves: int = 24,
                   hidden: np.ndarray | None = None, coverage: np.ndarray | None = None) -> Framing:
    """The framing near the aim ``uv`` (real pixels), window ``side`` (pixels) and roll ``roll_rad`` (see the
    module doc) whose crop of ``rgb`` (H, W, 3) uint8 with intrinsics ``K`` best matches the templates
    ``weights`` (:func:`~simtest.estimators.templates.match.template_weights`); crops of ``size`` pixels;
    ``shift`` and ``min_shift`` are fractions of the side, ``scale`` a step of its log, ``roll_deg`` degrees;
    ``max_moves`` bounds the accepted moves; ``hidden`` (H, W) bool: pixels left out of the scores, with the
    templates' ``coverage`` (:func:`~simtest.estimators.templates.match.template_coverage`)."""
    here = np.array([float(uv[0]), float(uv[1]), np.log(float(side)), float(roll_rad)])

    def crops_at(params: np.ndarray) -> list[Crop]:
        return [aimed_crop(rgb, K, p[:2], float(np.exp(p[2])), float(p[3]), size) for p in params]

    def best_of(crops: list[Crop]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        q = encoder.features(np.stack([c.rgb for c in crops]))
        scores = match_scores(q, weights, hidden=hidden_cells(hidden, K, crops, q.shape[-2:]), coverage=coverage)
        return q, scores.max(axis=1), scores.argmax(axis=1)

    (crop,) = crops_at(here[None])
    q, s, j = best_of([crop])
    best = (crop, int(j[0]), float(s[0]), q[0], float(here[3]))
    n, moves = 1, 0
    step = np.array([shift, shift, scale, np.radians(roll_deg)], np.float64)
    while step[0] >= min_shift - 1e-12 and moves < max_moves:
        side_now = float(np.exp(here[2]))
        params = here + _MOVES * step * np.array([side_now, side_now, 1.0, 1.0])
        crops = crops_at(params)
        q, s, j = best_of(crops)
        n += len(crops)
        k = int(np.argmax(s))
        if s[k] > best[2]:
            here, best, moves = params[k], (crops[k], int(j[k]), float(s[k]), q[k], float(params[k][3])), moves + 1
        else:
            step = step / 2.0
    return Framing(crop=best[0], template=best[1], score=best[2], query=best[3], roll_rad=best[4], crops=n)
