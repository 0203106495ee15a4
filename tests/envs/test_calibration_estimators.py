"""Metric calibration with real estimators, with real closed-loop episodes (a few seeded episodes of can_0).

The oracle's default run is checked against the rows its code wrote before real estimators were added (the
same seeds give the same scenes, errors and outcomes), the estimator runs for what they write: the
``estimator`` column, infinite errors for a miss, VSD, the per-estimator table, the same CSV with 1 or 2
workers.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

from simtest.cli import main
from simtest.envs.calibration import (EPISODE_COLUMNS, ESTIMATOR_COLUMNS, ESTIMATOR_EPISODE_COLUMNS, METRICS,
                                      VSD_METRICS, CalibrationConfig, calibrate_rows, run_calibration)
from simtest.envs.oracle_episodes import EpisodeSetup, episode_seed_of
from simtest.errors import ConfigError
from simtest.io.files import read_csv

#: ``calibration_episodes.csv`` of ``simtest calibrate --objects builtin-small --episodes 4`` (seed 0) before
#: real estimators were added: the rows of can_0's episodes 0 and 1, less ``wall_s``. Re-pinned when dressed
#: scenes moved onto the pool model (its looks slots): the settled poses' rounding moved the last digits of the
#: grasp errors (about 1e-8 relative); every outcome and the estimates' errors are as before.
ORACLE_CAN_ROWS = [
    "can_0,1,0,1921337475,L0,35.68127849387447,14.149179655576976,0,slipped,0.02297767213287566,"
    "8.207269949262901,0.03568127849387447,0.04067787515168489,59.29009008466309",
    "can_0,1,1,3023734987,L1,9.41690571099668,16.073421793816916,1,none,0.006379408212866326,"
    "9.192852859754794,0.009416905710996683,0.01745524451499199,21.53390649994655",
]


def _same_rows(got: list[str], want: list[str]) -> bool:
    """Rows equal field by field: text exactly, numbers to 1e-9 relative (the same machine writes the same
    bytes; another CPU's vector paths in MuJoCo and NumPy may change the last bits of a float)."""
    if len(got) != len(want):
        return False
    for g_row, w_row in zip(got, want):
        g, w = g_row.split(","), w_row.split(",")
        if len(g) != len(w):
            return False
        for a, b in zip(g, w):
            try:
                fa, fb = float(a), float(b)
            except ValueError:
                if a != b:
                    return False
                continue
            if not math.isclose(fa, fb, rel_tol=1e-9, abs_tol=1e-12):
                return False
    return True


def _rows_without_wall(path) -> list[str]:
    lines = path.read_text().splitlines()
    return [",".join(line.split(",")[:-1]) for line in lines]  # wall_s is the last column


def test_oracle_default_is_unchanged(tmp_path):
    out = tmp_path / "oracle"
    assert main(["calibrate", "--objects", "builtin-small", "--target", "can_0", "--episodes", "2",
                 "--resamples", "20", "--quiet", "--out", str(out)]) == 0
    lines = _rows_without_wall(out / "calibration_episodes.csv")
    assert lines[0] == ",".join(EPISODE_COLUMNS[:-1])
    assert _same_rows(lines[1:], ORACLE_CAN_ROWS), (lines[1:], ORACLE_CAN_ROWS)
    assert not (out / "calibration_estimators.csv").exists()
    assert [r["metric"] for r in read_csv(out / "calibration.csv")] == [m.key for m in METRICS]
    summary = json.loads((out / "calibration.json").read_text())
    assert "estimators" not in summary and "estimators" not in summary["config"]
    assert summary["config"]["setup"]["width"] == 64 and "vsd" not in summary["config"]["setup"]


@pytest.fixture(scope="module")
def pooled():
    """icp and keypoints at 320x240 on the same two can_0 scenes (L0, L1); keypoints finds no can at L1."""
    cfg = CalibrationConfig(setup=EpisodeSetup(objects="builtin-small", width=320, height=240), targets=("can_0",),
                            episodes_per_object=2, estimators=("icp", "keypoints"), resamples=20, seed=0)
    return run_calibration(cfg, progress=False)


def test_estimator_episodes_are_the_oracles_scenes(pooled):
    rows = pooled.episodes
    assert [(r["estimator"], r["episode"], r["occlusion"]) for r in rows] == [
        ("icp", 0, "L0"), ("icp", 1, "L1"), ("keypoints", 0, "L0"), ("keypoints", 1, "L1")]
    assert [r["seed"] for r in rows] == [episode_seed_of(0, 1, j, 1) for j in (0, 1)] * 2
    assert pooled.summary["config"]["setup"]["vsd"] is True
    assert pooled.summary["config"]["estimators"] == ("icp", "keypoints")


def test_a_miss_is_a_failure_with_infinite_error(pooled):
    miss = pooled.episodes[3]
    assert (miss["estimator"], miss["reason"], miss["success"]) == ("keypoints", "no_estimate", False)
    assert all(miss[k] == math.inf for k in ("add_s", "re_sym_deg", "te", "mssd", "mspd", "vsd"))
    found = pooled.episodes[0]
    assert found["reason"] == "none" and found["te"] < 0.005 and 0.0 <= found["vsd"] < 0.1
    assert len(found["vsd_taus"].split()) == 10
    by = {r["metric"]: r for r in pooled.metrics}
    assert [r["metric"] for r in pooled.metrics] == [m.key for m in METRICS + VSD_METRICS]
    assert all(r["episodes"] == 4 for r in pooled.metrics)  # the miss counts, as the largest error
    assert by["te"]["threshold_90"] is None or math.isfinite(by["te"]["threshold_90"])
    assert pooled.summary["estimators"]["keypoints"]["misses"] == 1


def test_per_estimator_table(pooled):
    te = [r for r in pooled.per_estimator if r["metric"] == "te"]
    assert [r["estimator"] for r in te] == ["icp", "keypoints"]
    for r in te:
        mine = [e for e in pooled.episodes if e["estimator"] == r["estimator"]]
        assert (r["episodes"], r["successes"]) == (2, sum(bool(e["success"]) for e in mine))
        assert r["ci95_lo"] <= r["success_rate"] <= r["ci95_hi"]
    assert set(pooled.per_estimator[0]) == set(ESTIMATOR_COLUMNS)


def test_same_seed_same_csv_with_one_and_two_workers(tmp_path, capsys):
    args = ["calibrate", "--objects", "builtin-small", "--target", "can_0", "--estimator", "icp",
            "--episodes", "2", "--width", "160", "--resamples", "20", "--seed", "3", "--quiet"]
    assert main([*args, "--out", str(tmp_path / "w1")]) == 0
    assert main([*args, "--workers", "2", "--out", str(tmp_path / "w2")]) == 0
    one = _rows_without_wall(tmp_path / "w1" / "calibration_episodes.csv")
    assert one == _rows_without_wall(tmp_path / "w2" / "calibration_episodes.csv")
    assert one[0] == ",".join(ESTIMATOR_EPISODE_COLUMNS[:-1]) and len(one) == 3
    assert all(line.startswith("icp,can_0,1,") for line in one[1:])
    for name in ("calibration.csv", "calibration_estimators.csv", "calibration_thresholds.csv"):
        assert (tmp_path / "w1" / name).read_text() == (tmp_path / "w2" / name).read_text()
    summary = json.loads((tmp_path / "w1" / "calibration.json").read_text())
    assert summary["config"]["setup"]["width"] == 160 and set(summary["estimators"]) == {"icp"}
    out = capsys.readouterr().out
    assert "icp: " in out and "| VSD (mean over tau) |" in out
    assert "Estimates of real estimators" in (tmp_path / "w1" / "calibration.html").read_text()


def test_infinite_errors_rank_last():
    rows = [{"estimator": "x", "success": s, "add_s": e, "mssd": e, "mspd": e, "re_sym_deg": e, "te": e,
             "diameter_m": 0.1} for s, e in ((True, 0.001), (True, 0.002), (False, 0.003), (False, math.inf))]
    table, _ = calibrate_rows(rows, resamples=20)
    by = {r["metric"]: r for r in table}
    assert by["te"]["auc"] == 1.0 and by["te"]["episodes"] == 4
    assert by["te"]["best_threshold"] == pytest.approx(2.0)  # mm
    # Without an estimator name (oracle rows) an infinite value is no error at all, as before.
    oracle = [{k: v for k, v in r.items() if k != "estimator"} for r in rows]
    assert calibrate_rows(oracle, resamples=20)[0][0]["episodes"] == 3
    assert np.isfinite([r["auc"] for r in table]).all()


def test_bad_settings_are_named():
    with pytest.raises(ConfigError, match="distinct real estimators"):
        CalibrationConfig(estimators=("oracle", "icp")).check()
    with pytest.raises(ConfigError, match="not in the run"):
        CalibrationConfig(estimators=("icp",), estimator_options={"segicp": {"flip": True}}).check()
    from simtest.cli.calibrate import estimator_options
    with pytest.raises(ConfigError, match="needs --estimator"):
        estimator_options((), ["seed=1"])
    with pytest.raises(ConfigError, match="'keypoints', not one of"):
        estimator_options(("icp",), ["keypoints:seed=1"])
    with pytest.raises(ConfigError, match="max_iterations"):
        estimator_options(("icp",), ["no_such_option=1"])
    assert estimator_options(("icp", "segicp"), ["seed=2", "icp:max_iterations=10"]) == {
        "icp": {"seed": 2, "max_iterations": 10}, "segicp": {"seed": 2}}


def test_oracle_error_bounds_are_refused_with_estimators_before_any_output(tmp_path, capsys):
    from simtest.cli import main

    out = tmp_path / "never"
    assert main(["calibrate", "--estimator", "icp", "--max-trans-mm", "20", "--episodes", "1", "--out", str(out)]) == 2
    assert "drop them" in capsys.readouterr().err and not out.exists()
