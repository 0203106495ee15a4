"""BOP24 detection AP equals the BOP toolkit's on a hand-made results file.

How the frozen numbers were produced: ``data/bop24_hand/ds`` holds the ground truth (``scene_gt.json``,
``scene_gt_info.json``, ``scene_camera.json``, manifest; images left out, MSSD / MSPD need none) of
``simtest generate --objects builtin-small --scenes 2 --frames-per-scene 3 --objects-per-scene 4 6 --width 320
--height 240 --seed 7``; ``data/bop24_hand/results.csv`` was written by ``data/bop24_hand/make_results.py`` on
that dataset (exact and perturbed poses, misses, duplicates, a false positive far away, an exact estimate of an
instance with visib_fract 0.08 and a miss-placed one of an instance with visib_fract 0.0, an estimate of an
object absent from its image, tied scores, an image without estimates, and an image with 106 estimates of
which 6 fall under the 100-per-image cut). The BOP toolkit (thodan/bop_toolkit at cea62d6) ran its own
``scripts/eval_bop24_pose.py --num_workers 1 --renderer_type python`` on that file, with the dataset laid out as
``simtest/{test -> train_pbr, models_eval -> models, camera.json, test_targets_bop24.json}`` and a
``"simtest"`` entry (object ids 1, 7, 13, 22; scenes 0, 1; 320x240) added to its ``dataset_params.py``; the
numbers below are its ``scores_bop24.json`` and the per-object means of its ``scores_th=*.json``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from simtest.metrics.bop24 import THRESHOLDS, average_precision, greedy_match, keep_top_per_image
from simtest.metrics.bop19 import ResultRow

DATA = Path(__file__).parent / "data" / "bop24_hand"

#: The toolkit's scores_bop24.json.
TOOLKIT = {"ap": 0.4198387531479628, "ap_mssd": 0.43379044197973793, "ap_mspd": 0.4058870643161877,
           "ap_mssd_mm": 0.3076172795851014}
#: Per object: the mean over thresholds of the toolkit's per-threshold APs.
TOOLKIT_PER_OBJECT = {
    "ap_mssd": {1: 0.4628712871287129, 7: 0.2884488448844884, 13: 0.4786138613861385, 22: 0.5052277745196122},
    "ap_mssd_mm": {1: 0.4628712871287129, 7: 0.21254125412541253, 13: 0.18514851485148515,
                   22: 0.3699080622347949},
    "ap_mspd": {1: 0.523019801980198, 7: 0.30363036303630364, 13: 0.30475247524752475, 22: 0.49214561700072446},
}


@pytest.fixture(scope="module")
def report():
    from simtest.evaluation.run import score_results

    return score_results(DATA / "results.csv", DATA / "ds", vsd=False, progress=False, task="detection")


def test_ap_equals_the_toolkit_on_hand_made_results(report):
    for k, v in TOOLKIT.items():
        assert report.overall[k] == pytest.approx(v, abs=1e-12), k
    for k, per in TOOLKIT_PER_OBJECT.items():
        for obj_id, v in per.items():
            assert report.per_object[obj_id][k] == pytest.approx(v, abs=1e-12), (k, obj_id)
    assert report.settings["task"] == "detection"
    assert report.overall["num_gt_visible"] == report.overall["num_targets"] == 34


def test_the_100_estimate_cut_is_applied_per_image(report):
    assert len(report.estimates) == 131 - 6
    low = [r for r in report.estimates if (r.scene_id, r.im_id) == (1, 2)]
    assert len(low) == 100 and min(r.score for r in low) > 0.0001


def test_average_precision_of_the_toolkit_example():
    # bop_toolkit_lib/score.py's own check: tp = F T T F T F over 6 targets; COCO 101-point interpolation.
    tp = [False, True, True, False, True, False]
    rec = np.cumsum(tp) / 6
    pre = np.cumsum(tp) / np.arange(1, 7)
    expected = np.mean([max([p for r, p in zip(rec, pre) if r >= t], default=0.0) for t in np.linspace(0, 1, 101)])
    assert average_precision(tp, 6) == pytest.approx(expected)
    assert average_precision([], 3) == 0.0 and average_precision([True], 1) == 1.0


def test_greedy_matching_is_strict_and_one_to_one():
    err = np.array([[0.1, 0.05], [0.04, 0.2], [0.01, 0.01]])
    assert greedy_match(err, 0.1) == [1, 0, -1]  # 0.1 is not below 0.1; the third finds both taken
    assert greedy_match(err, 0.5) == [1, 0, -1]
    assert greedy_match(np.array([[0.3, 0.3]]), 0.5) == [0]  # ties: the first instance


def test_keep_top_per_image_keeps_the_highest_scores_stably():
    R, t = np.eye(3), np.zeros(3)
    rows = [ResultRow(0, 0, 1, s, R, t, 0.0) for s in (0.2, 0.9, 0.5, 0.9)] + [ResultRow(0, 1, 1, 0.1, R, t, 0.0)]
    kept = keep_top_per_image(rows, limit=3)
    assert [r.score for r in kept] == [0.9, 0.9, 0.5, 0.1] and kept[0] is rows[1] and kept[1] is rows[3]


def test_thresholds_are_the_toolkits():
    assert len(THRESHOLDS["mssd"]) == 10 and THRESHOLDS["mssd"][0] == 0.05 and THRESHOLDS["mssd"][-1] == pytest.approx(0.5)
    assert np.allclose(np.asarray(THRESHOLDS["mssd_mm"]) * 1000, range(2, 21, 2))  # metres: the toolkit's 2..20 mm
    assert THRESHOLDS["mspd"] == tuple(float(x) for x in range(5, 51, 5))
