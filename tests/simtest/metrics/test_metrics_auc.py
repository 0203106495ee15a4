"""YCB-Video AUC and fixed-threshold accuracy on hand-computed distance lists (metres)."""

from __future__ import annotations

import numpy as np
import pytest

from simtest.errors import ConfigError
from simtest.metrics import accuracy_below, auc_mean_rule, ycb_auc


def _voc_loop(distances, thr=0.1):
    """The YCB-Video toolbox's VOCap written as loops, for comparison."""
    d = np.sort(np.where(np.asarray(distances) > thr, np.inf, distances))
    n = len(d)
    acc = np.arange(1, n + 1) / n
    keep = np.isfinite(d)
    if not keep.any():
        return 0.0
    mrec = [0.0] + list(d[keep]) + [thr]
    mpre = [0.0] + list(acc[keep]) + [acc[keep][-1]]
    for i in range(1, len(mpre)):
        mpre[i] = max(mpre[i], mpre[i - 1])
    area = 0.0
    for i in range(1, len(mrec)):
        if mrec[i] != mrec[i - 1]:
            area += (mrec[i] - mrec[i - 1]) * mpre[i]
    return area / thr


def test_hand_computed_list():
    d = [0.0, 0.05, np.inf, 0.2]
    # Finite after clipping: 0 and 0.05 with accuracies 1/4 and 2/4; area = 0.05 * 0.5 + 0.05 * 0.5.
    assert ycb_auc(d) == pytest.approx(0.5)
    assert auc_mean_rule(d) == pytest.approx((1.0 + 0.5) / 4)
    # The difference is the right-endpoint term: largest finite distance / (n * 0.1).
    assert ycb_auc(d) - auc_mean_rule(d) == pytest.approx(0.05 / (4 * 0.1))


def test_extremes():
    assert ycb_auc([0.0, 0.0]) == pytest.approx(1.0)
    assert ycb_auc([np.inf, 0.5]) == 0.0
    assert auc_mean_rule([np.inf, 0.5]) == 0.0
    # A distance of exactly 0.1 m stays finite and, by the right-endpoint rule, scores fully.
    assert ycb_auc([0.1]) == pytest.approx(1.0)
    assert auc_mean_rule([0.1]) == 0.0


def test_matches_the_reference_loop_and_the_closed_form_relation():
    rng = np.random.default_rng(3)
    d = rng.exponential(0.03, size=200)
    d[rng.random(200) < 0.1] = np.inf
    got = ycb_auc(d)
    assert got == pytest.approx(_voc_loop(d), abs=1e-12)
    finite = d[d <= 0.1]
    assert got == pytest.approx(auc_mean_rule(d) + finite.max() / (len(d) * 0.1), abs=1e-12)
    # Ties do not change the value.
    assert ycb_auc([0.02, 0.02, 0.06]) == pytest.approx(_voc_loop([0.02, 0.02, 0.06]))


def test_accuracy_below_is_strict():
    assert accuracy_below([0.01, 0.02, 0.03]) == pytest.approx(1 / 3)
    assert accuracy_below([0.01, np.inf], 0.05) == 0.5


def test_bad_inputs():
    with pytest.raises(ConfigError, match="empty"):
        ycb_auc([])
    with pytest.raises(ConfigError, match="NaN"):
        ycb_auc([0.01, np.nan])
    with pytest.raises(ConfigError, match="-0.01"):
        auc_mean_rule([-0.01])
    with pytest.raises(ConfigError, match="threshold"):
        accuracy_below([0.01], 0.0)
