"""Pooling evaluation runs: real evaluations of a generated dataset, scored alone and together."""

from __future__ import annotations

import json

import numpy as np
import pytest

from simtest.errors import DatasetError
from simtest.evaluation.pooled import pool_runs, read_error_rows, write_pooled
from simtest.evaluation.run import evaluate


@pytest.fixture(scope="module")
def two_runs(small_dataset, tmp_path_factory):
    """The oracle with noise on scene 0 and on scene 1 of the small dataset: two runs, one scene each."""
    root = tmp_path_factory.mktemp("pool")
    runs = []
    for scene in (0, 1):
        out = root / f"run{scene}"
        evaluate(small_dataset, "oracle", scenes=[scene], progress=False, out_dir=out, vsd=False,
                 estimator_options={"rot_noise_deg": 8.0, "trans_noise_mm": 8.0})
        runs.append(out)
    return runs


def test_pooled_score_is_the_union_of_the_runs(two_runs):
    score = pool_runs(two_runs)
    n = [len(read_error_rows(r)) for r in two_runs]
    assert score.pooled["num_targets"] == sum(n)
    hits = [m["add_s_or_add_01d"] * m["num_targets"] for m in score.per_run]
    assert np.isclose(score.pooled["add_s_or_add_01d"], sum(hits) / sum(n))
    # one scene per run, but the pooled score resamples the two (run, scene) pairs
    assert score.pooled["num_scenes"] == 2 and "ci95_scenes" in score.pooled
    lo, hi = score.pooled["ci95_scenes"]["add_s_or_add_01d"]
    assert lo <= score.pooled["add_s_or_add_01d"] <= hi
    assert score.spread() == pytest.approx(abs(score.per_run[0]["add_s_or_add_01d"]
                                                - score.per_run[1]["add_s_or_add_01d"]))
    assert score.estimators == ("oracle", "oracle")


def test_pooled_files_are_written(two_runs, tmp_path):
    j, m = write_pooled(pool_runs(two_runs), tmp_path / "pooled")
    data = json.loads(j.read_text())
    assert data["pooled"]["num_targets"] == sum(r["num_targets"] for r in data["per_run"])
    assert "**pooled**" in m.read_text()


def test_bad_runs_are_named(two_runs, tmp_path):
    with pytest.raises(DatasetError, match="errors.csv"):
        pool_runs([two_runs[0], tmp_path])
    with pytest.raises(DatasetError, match="twice"):
        pool_runs([two_runs[0], two_runs[0]])
    bad = tmp_path / "bad"
    bad.mkdir()
    (bad / "errors.csv").write_text((two_runs[0] / "errors.csv").read_text().replace(",1,", ",x,", 1)
                                    .replace("visib_fract", "visibility", 1))
    with pytest.raises(DatasetError, match="visib_fract"):
        read_error_rows(bad)
