"""Local template search: templates rendered on the fly around the best bank match, kept while they match better.

The bank's views lie several degrees apart; around the best one, templates are rendered at rotations turned by
``±step`` about each axis of the crop camera (6 per round), encoded and scored against the same query crop as
the bank (:func:`~simtest.estimators.templates.match.match_scores`); the best replaces the current one while it
scores higher (up to ``rounds`` moves per step), then the step halves, down to ``min_step_deg``.
"""

from __future__ import annotations

import cv2
import numpy as np

from simtest.estimators.templates.bank import BankSettings, TemplateBank, render_templates
from simtest.estimators.templates.encoder import FeatureEncoder
from simtest.estimators.templates.match import match_scores, template_coverage, template_weights
from simtest.estimators.templates.render import ObjectRenderer

__all__ = ["local_search"]

_AXES = np.concatenate([np.eye(3), -np.eye(3)])


def local_search(renderer: ObjectRenderer, settings: BankSettings, encoder: FeatureEncoder, query: np.ndarray,
                 query_mask: np.ndarray | None, R_start: np.ndarray, score: float, step_deg: float = 4.0,
                 min_step_deg: float = 1.0, rounds: int = 2, hidden: np.ndarray | None = None
                 ) -> tuple[TemplateBank | None, float, int]:
    """The best template found around rotation ``R_start`` (model to crop camera) for one query crop's unit
    features ``query`` (C, h, w), cell mask ``query_mask`` (h, w) or None and hidden cells ``hidden`` (h, w) or
    None (:func:`~simtest.estimators.templates.match.match_scores`), whose bank match scored ``score``:
    ``(a one-template bank, or None when nothing scored higher; its score; templates rendered)``."""
    best, best_R, best_score, n = None, np.asarray(R_start, np.float64), float(score), 0
    step = float(step_deg)
    qm = None if query_mask is None else query_mask[None]
    while step >= float(min_step_deg) - 1e-9:
        for _ in range(int(rounds)):
            rots = np.stack([cv2.Rodrigues(np.radians(step) * a.reshape(3, 1))[0] @ best_R for a in _AXES])
            cand = render_templates(renderer, rots, settings, encoder)
            n += len(rots)
            hid, cover = (None, None) if hidden is None else (hidden[None], template_coverage(cand))
            s = match_scores(query[None], template_weights(cand), qm, hid, cover)[0]
            k = int(np.argmax(s))
            if s[k] <= best_score:
                break
            best_score, best_R = float(s[k]), rots[k]
            best = TemplateBank(feats=cand.feats[k:k + 1], masks=cand.masks[k:k + 1], R=cand.R[k:k + 1],
                                t=cand.t[k:k + 1], K=cand.K[k:k + 1], directions=cand.directions[k:k + 1],
                                settings=settings)
        step /= 2.0
    return best, best_score, n
