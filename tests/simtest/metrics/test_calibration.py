"""ROC AUC as the Mann-Whitney statistic, its bootstrap interval, thresholds and tolerances, on tables worked
out by hand."""

from __future__ import annotations

import math

import pytest

from simtest.metrics.calibration import (best_threshold, bootstrap_auc_interval, mann_whitney_u, roc_auc,
                                         success_below)
from simtest.metrics.tolerance import largest_tolerated

# Errors (mm) of three grasps that held and four that failed.
SUCCESS_ERRORS = [1.0, 2.0, 4.0]
FAILURE_ERRORS = [3.0, 4.0, 5.0, 6.0]
ERRORS = SUCCESS_ERRORS + FAILURE_ERRORS
SUCCESS = [True] * 3 + [False] * 4


def test_auc_is_the_mann_whitney_statistic_of_a_hand_table():
    # Pairs (failure f, success s) with f > s: f=3 beats 1, 2 (2); f=4 beats 1, 2 and ties 4 (2.5);
    # f=5 and f=6 beat all three (3 + 3). U = 10.5 of 4 x 3 = 12 pairs.
    assert mann_whitney_u(FAILURE_ERRORS, SUCCESS_ERRORS) == 10.5
    assert roc_auc(ERRORS, SUCCESS) == pytest.approx(10.5 / 12)
    assert roc_auc([1, 2, 3, 4], [True, True, False, False]) == 1.0  # a perfect separation
    assert roc_auc([1, 2, 3, 4], [False, False, True, True]) == 0.0
    assert roc_auc([5, 5, 5, 5], [True, False, True, False]) == 0.5  # all ties: chance
    assert math.isnan(roc_auc([1, 2], [True, True]))  # one outcome only


def test_episodes_without_an_error_are_left_out():
    assert roc_auc(ERRORS + [float("nan")], SUCCESS + [False]) == pytest.approx(10.5 / 12)
    with pytest.raises(ValueError, match="same length"):
        roc_auc([1.0, 2.0], [True])


def test_bootstrap_interval_holds_the_auc_and_repeats():
    lo, hi = bootstrap_auc_interval(ERRORS, SUCCESS, resamples=200, seed=3)
    assert 0.0 <= lo <= 10.5 / 12 <= hi <= 1.0
    assert (lo, hi) == bootstrap_auc_interval(ERRORS, SUCCESS, resamples=200, seed=3)
    with pytest.raises(ValueError, match="resamples"):
        bootstrap_auc_interval(ERRORS, SUCCESS, resamples=5)


def test_best_threshold_and_success_below():
    # Predict success when error <= t: t=2 keeps 2 of 3 successes and no failure (J = 2/3, the best).
    th = best_threshold(ERRORS, SUCCESS)
    assert th.threshold == 2.0 and th.youden == pytest.approx(2 / 3)
    assert (th.tpr, th.fpr) == (pytest.approx(2 / 3), 0.0)
    assert success_below(ERRORS, SUCCESS, 4.0) == (3, 5)  # 1, 2, 4 held; 3, 4 failed


def test_largest_tolerated_stops_at_the_first_dip():
    tol = largest_tolerated([0, 5, 10, 20], [10, 9, 7, 10], [10, 10, 10, 10], level=0.9)
    assert (tol.tolerated, tol.first_below, tol.reaches_zero) == (5.0, 10.0, False)
    tol = largest_tolerated([20, 0, 10], [0, 10, 10], [10, 10, 10])  # any order
    assert (tol.tolerated, tol.first_below, tol.reaches_zero) == (10.0, 20.0, True)
    tol = largest_tolerated([0, 10], [10, 10], [10, 10])
    assert (tol.tolerated, tol.first_below) == (10.0, None)
    with pytest.raises(ValueError, match="successes <= episodes"):
        largest_tolerated([0], [3], [2])
