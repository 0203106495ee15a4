"""95 % intervals: Wilson's for proportions (values of the literature), the normal one for means, and the
evaluation report's intervals agree with its own per-target errors."""

from __future__ import annotations

import csv
import json

import pytest

from simtest.metrics.intervals import cluster_bootstrap_interval, mean_interval, wilson_interval


def test_wilson_interval_known_values_and_ends():
    # Newcombe (1998), Table I: 81/263 -> 0.2553..0.3662
    lo, hi = wilson_interval(81, 263)
    assert lo == pytest.approx(0.2553, abs=5e-4) and hi == pytest.approx(0.3662, abs=5e-4)
    assert wilson_interval(0, 10)[0] == 0.0 and wilson_interval(10, 10)[1] == 1.0
    assert wilson_interval(0, 0) == (0.0, 1.0)
    with pytest.raises(ValueError, match="successes"):
        wilson_interval(11, 10)


def test_mean_interval():
    lo, hi = mean_interval([0.0, 1.0] * 50)
    assert lo == pytest.approx(0.5 - 1.96 * 0.50252 / 10, abs=1e-3) and hi == pytest.approx(1 - lo, abs=1e-9)
    assert mean_interval([0.3]) == (0.0, 1.0)


def test_the_report_gives_each_proportion_its_interval(small_dataset, tmp_path):
    from simtest.evaluation.run import evaluate

    rep = evaluate(small_dataset, "oracle", estimator_options={"rot_noise_deg": 8.0, "trans_noise_mm": 12.0},
                   out_dir=tmp_path / "run", vsd=False, progress=False)
    with open(tmp_path / "run" / "errors.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    hits = sum(float(r["add_s_or_add"]) < 0.1 * float(r["diameter_m"]) for r in rows if r["matched"] == "1")
    ci = json.loads((tmp_path / "run" / "metrics.json").read_text())["overall"]["ci95"]
    assert ci["add_s_or_add_01d"] == pytest.approx(list(wilson_interval(hits, len(rows))))
    for key, (lo, hi) in ci.items():
        assert lo <= rep.overall[key] <= hi, key
    for m in rep.per_object.values():
        assert set(m["ci95"]) == set(ci)
    md = (tmp_path / "run" / "metrics.md").read_text()
    assert "95 % intervals (Wilson, over targets): ADD(-S)-0.1d" in md
    # two scenes: the interval over scenes is the bootstrap of the scene-clustered hits, and it is printed
    scenes = [int(r["scene_id"]) for r in rows]
    assert len(set(scenes)) == 2
    hit = [float(float(r["add_s_or_add"]) < 0.1 * float(r["diameter_m"])) if r["matched"] == "1" else 0.0
           for r in rows]
    by_scene = json.loads((tmp_path / "run" / "metrics.json").read_text())["overall"]["ci95_scenes"]
    assert by_scene["add_s_or_add_01d"] == pytest.approx(list(cluster_bootstrap_interval(hit, scenes)))
    assert "95 % intervals (bootstrap over 2 scenes" in md


def test_cluster_bootstrap_interval_resamples_whole_scenes():
    """Two scenes of 10 targets, one all correct and one all wrong: the replicates are 1, 0.5, 0.5 and 0 (each
    pair of scenes equally likely), so the 95 % interval is [0, 1], where Wilson over the 20 targets as if
    independent gives [0.30, 0.70]; the same seed gives the same interval; one scene gives none."""
    values, scenes = [1.0] * 10 + [0.0] * 10, [0] * 10 + [1] * 10
    assert cluster_bootstrap_interval(values, scenes) == (0.0, 1.0)
    assert wilson_interval(10, 20) == pytest.approx((0.299, 0.701), abs=1e-3)
    mixed = [1.0, 0.0] * 10
    a = cluster_bootstrap_interval(mixed, [i // 2 for i in range(20)], seed=3)
    assert a == cluster_bootstrap_interval(mixed, [i // 2 for i in range(20)], seed=3)
    assert a == (0.5, 0.5)  # every scene holds one hit in two targets: no spread between scenes
    assert cluster_bootstrap_interval([1.0, 0.0], ["a", "a"]) is None
    with pytest.raises(ValueError, match="same length"):
        cluster_bootstrap_interval([1.0], [0, 1])
