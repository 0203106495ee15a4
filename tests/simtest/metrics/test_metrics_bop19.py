"""BOP19 matching, recall and Average Recall on small hand-made cases."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from simtest.errors import ConfigError
from simtest.metrics import EvalImage, GroundTruthPose, ResultRow, evaluate_bop19, match_greedy, mspd, vsd
from simtest.metrics.bop19 import MSPD_THETAS, MSSD_THETAS, VSD_TAUS, VSD_THETAS
from simtest.objects import ObjectModel
from simtest.render.zbuffer import render_depth

K = np.array([[300.0, 0.0, 159.5], [0.0, 300.0, 119.5], [0.0, 0.0, 1.0]])
W, H = 320, 240
I3 = np.eye(3)
T0 = np.array([0.0, 0.0, 0.6])


@pytest.fixture(scope="module")
def box() -> ObjectModel:
    return ObjectModel(3, "box", "box", 0, trimesh.creation.box(extents=(0.1, 0.06, 0.04)))


@pytest.fixture(scope="module")
def image(box) -> EvalImage:
    depth = render_depth(box.vertices, box.faces, I3, T0, K, W, H)
    return EvalImage(K, W, H, depth)


def _gt(t=T0, gt_id=0, visib=1.0, obj_id=3):
    return GroundTruthPose(1, 0, gt_id, obj_id, I3, t, visib)


def _est(t, score, obj_id=3):
    return ResultRow(1, 0, obj_id, score, I3, t)


def test_match_greedy_two_estimates_one_gt_only_the_higher_score_matches():
    errors = np.array([[0.02], [0.01]])  # the second estimate is more accurate but less confident
    assert match_greedy([0.9, 0.5], errors, threshold=0.05) == [(0, 0)]
    # Each estimate takes the lowest-error unmatched GT below the threshold; invalid GTs are skipped.
    errors = np.array([[0.03, 0.01, 0.0], [0.02, 0.04, 0.0]])
    assert match_greedy([0.9, 0.8], errors, 0.05, gt_valid=[True, True, False]) == [(0, 1), (1, 0)]
    assert match_greedy([0.9, 0.8], errors, 0.025, gt_valid=[True, True, False]) == [(0, 1), (1, 0)]
    assert match_greedy([0.9, 0.8], errors, 0.015, gt_valid=[True, True, False]) == [(0, 1)]
    # Strict threshold.
    assert match_greedy([1.0], np.array([[0.05]]), 0.05) == []


def test_perfect_estimate_gives_ar_one_and_n_top_keeps_the_most_confident(box, image):
    models, images = {3: box}, {(1, 0): image}
    good, bad = T0, T0 + [0.2, 0.0, 0.0]
    res = evaluate_bop19([_est(good, 0.9), _est(bad, 0.5)], [_gt()], models, images)
    assert res.ar == pytest.approx(1.0) and res.num_targets == 1 and res.num_estimates == 1
    assert res.recall_vsd.shape == (len(VSD_TAUS), len(VSD_THETAS))
    # The wrong estimate is more confident: with n_top = -1 (one target) only it is evaluated.
    res = evaluate_bop19([_est(good, 0.5), _est(bad, 0.9)], [_gt()], models, images)
    assert res.ar == 0.0
    # With every estimate kept, the wrong one fails to match and the right one still matches.
    res = evaluate_bop19([_est(good, 0.5), _est(bad, 0.9)], [_gt()], models, images, n_top=0)
    assert res.ar == pytest.approx(1.0) and res.num_estimates == 2
    # Estimates of other objects, or of no image, are ignored.
    res = evaluate_bop19([_est(good, 0.9, obj_id=4)], [_gt()], models, images)
    assert res.ar == 0.0 and res.num_estimates == 0


def test_recalls_at_the_bop19_thresholds_for_a_lateral_shift(box, image):
    d = box.diameter
    t_e = T0 + [0.12 * d, 0.0, 0.0]
    res = evaluate_bop19([_est(t_e, 1.0)], [_gt()], {3: box}, {(1, 0): image})
    # MSSD = 0.12 d: correct for theta in {0.15, ..., 0.5}.
    np.testing.assert_array_equal(res.recall_mssd, np.array(MSSD_THETAS) > 0.12)
    e_mspd = mspd(I3, t_e, I3, T0, K, box.vertices) * 640 / W
    np.testing.assert_array_equal(res.recall_mspd, e_mspd < np.array(MSPD_THETAS))
    e_vsd = vsd(I3, t_e, I3, T0, image.depth, K, box, 0.015, VSD_TAUS, d)
    np.testing.assert_array_equal(res.recall_vsd, e_vsd[:, None] < np.array(VSD_THETAS)[None, :])
    assert res.ar_mssd == pytest.approx(0.8)
    assert res.ar == pytest.approx(np.mean([res.ar_vsd, res.ar_mssd, res.ar_mspd]))
    assert 0.0 < res.ar < 1.0
    assert res.per_object[3]["ar"] == pytest.approx(res.ar)


def test_visibility_filter_and_duplicate_estimates(box, image):
    models, images = {3: box}, {(1, 0): image}
    far = T0 + [0.15, 0.0, 0.0]
    gts = [_gt(), _gt(far, gt_id=1, visib=0.05)]
    ests = [_est(T0, 0.9), _est(far, 0.8)]
    res = evaluate_bop19(ests, gts, models, images, error_types=("mssd", "mspd"))
    # The barely visible instance is not a target: one target, matched.
    assert res.num_targets == 1 and res.ar == pytest.approx(1.0) and np.isnan(res.ar_vsd)
    res = evaluate_bop19(ests, gts, models, images, visib_gt_min=0.0, error_types=("mssd",))
    assert res.num_targets == 2 and res.ar == pytest.approx(1.0)
    # Two estimates on the same instance: one counts, the target count stays 2.
    res = evaluate_bop19([_est(T0, 0.9), _est(T0, 0.8)], gts, models, images, visib_gt_min=0.0,
                         error_types=("mssd",))
    assert res.ar == pytest.approx(0.5)


def test_bad_inputs(box, image):
    with pytest.raises(ConfigError, match="error_types"):
        evaluate_bop19([], [_gt()], {3: box}, {(1, 0): image}, error_types=("add",))
    with pytest.raises(ConfigError, match="visib_fract"):
        evaluate_bop19([], [_gt(visib=0.0)], {3: box}, {(1, 0): image})
    with pytest.raises(ConfigError, match="obj_id 3"):
        evaluate_bop19([_est(T0, 1.0)], [_gt()], {}, {(1, 0): image})
    with pytest.raises(ConfigError, match="depth"):
        evaluate_bop19([_est(T0, 1.0)], [_gt()], {3: box}, {(1, 0): EvalImage(K, W, H)})
    with pytest.raises(ConfigError, match="R must have 9"):
        ResultRow(1, 0, 3, 1.0, np.eye(2), T0)
