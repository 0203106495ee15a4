"""Clutter removal: a round with the oracle empties a 3-object table; the run's files and intervals."""

from __future__ import annotations

import csv
import json

import pytest

from simtest.envs.declutter import DeclutterTask, run_declutter, run_round
from simtest.envs.runner import GraspRunConfig, episode_seed
from simtest.errors import ConfigError
from simtest.estimators.oracle import OracleEstimator


@pytest.fixture(scope="module")
def task():
    t = DeclutterTask(width=96, height=72, episode={"objects": "builtin-small"})
    yield t
    t.close()


def test_oracle_round_empties_a_three_object_pile(task):
    res = run_round(task, OracleEstimator(), seed=episode_seed(0, 1), scene="pile", n=3, objects="builtin-small")
    assert res.objects == 3
    assert res.removed == 3 and res.dr == 1.0 and res.gsr == 1.0, res.attempt_rows
    assert task.remaining() == []
    assert all(a["estimates"] >= 1 for a in res.attempt_rows)


def test_packed_round_places_upright_objects_on_the_table(task):
    n = task.start_round(episode_seed(0, 3), "packed", 3, "builtin-small")
    assert n == 3 and len(task.remaining()) == 3
    with pytest.raises(ConfigError, match="'heap'"):
        task.start_round(0, "heap", 3)


def test_run_declutter_writes_rounds_with_intervals(tmp_path):
    cfg = GraspRunConfig(estimator="oracle", episodes=1, objects="builtin-small", width=96, height=72,
                         task="declutter", scene="pile", objects_per_scene=3)
    rep = run_declutter(cfg, tmp_path / "out", progress=False)
    s = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert s["rounds"] == 1 and s["config"]["scene"] == "pile"
    lo, hi = s["dr_ci95"]
    assert 0.0 <= lo <= s["dr"] <= hi <= 1.0
    rows = list(csv.DictReader((tmp_path / "out" / "attempts.csv").open()))
    assert len(rows) == rep.rounds[0].attempts and all(r["reason"] for r in rows)
    assert "GSR" in rep.table()
