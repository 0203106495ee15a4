"""Closed-loop episodes: the oracle grasps, broken or wrong estimators give recorded failures, the CLI."""

from __future__ import annotations

import csv
import json
from types import SimpleNamespace

import numpy as np
import pytest

from simtest.envs.episode import FAILURE_REASONS, run_episode
from simtest.envs.runner import episode_seed
from simtest.envs.summary import summarize
from simtest.metrics.intervals import wilson_interval
from simtest.estimators.base import PoseEstimate
from simtest.estimators.oracle import OracleEstimator


@pytest.mark.parametrize("target", ["box_1", "can_0"])
def test_oracle_grasps_builtin_objects(env, target):
    res = run_episode(env, OracleEstimator(), seed=3, options={"target": target})
    assert res.success, res
    assert res.reason == "none" and res.lift_height >= 0.10
    assert res.add_s < 1e-6 and res.te < 1e-9 and res.re_deg < 1e-3 and res.mssd < 1e-6
    assert res.visible_pixels > 50 and res.wall_s < 10.0
    assert res.target_name == target


class _Raises:
    def estimate(self, observation):
        raise RuntimeError("model weights not found")


class _NaN:
    def estimate(self, observation):
        return [SimpleNamespace(obj_id=observation.target_obj_ids[0], R=np.full((3, 3), np.nan), t=np.zeros(3))]


def _nothing(observation):
    return []


@pytest.mark.parametrize("estimator, reason", [(_Raises(), "estimator_error"), (_NaN(), "no_estimate"),
                                               (_nothing, "no_estimate")])
def test_broken_estimators_are_recorded_failures(env, estimator, reason):
    res = run_episode(env, estimator, seed=4, options={"target": "box_1"})
    assert not res.success and res.reason == reason
    assert reason in FAILURE_REASONS
    if reason == "estimator_error":
        assert "model weights not found" in res.error
    assert np.isnan(res.add_s)


class _Shifted:
    """Ground truth moved 10 cm sideways in the world (along the table), expressed in the camera frame."""

    needs_gt = True

    def __init__(self, env, shift_world):
        self.env = env.unwrapped
        self.shift = np.asarray(shift_world, dtype=np.float64)

    def estimate(self, observation):
        R_g, t_g = observation.gt_poses[0]
        R_world_cam = self.env.task._T_world_cam()[:3, :3]
        return [PoseEstimate(obj_id=observation.target_obj_ids[0], R=R_g, t=t_g + R_world_cam.T @ self.shift)]


def test_wrong_pose_misses(env):
    res = run_episode(env, _Shifted(env, [0.0, 0.10, 0.0]), seed=3, options={"target": "can_0"})
    assert res.reason == "missed", res
    assert res.te == pytest.approx(0.10, abs=1e-6)


def test_wilson_interval_and_seeds():
    lo, hi = wilson_interval(19, 20)
    assert lo == pytest.approx(0.7639, abs=1e-3) and hi == pytest.approx(0.9911, abs=1e-3)
    assert wilson_interval(0, 0) == (0.0, 1.0)
    assert episode_seed(0, 3) == episode_seed(0, 3) != episode_seed(0, 4) != episode_seed(1, 4)
    rows = [{"success": s, "target_name": n, "target_obj_id": i, "reason": "none" if s else "missed",
             "add_s": 0.0, "re_deg": 0.0, "te": 0.0, "mssd": 0.0, "wall_s": 1.0, "estimate_s": 0.0}
            for s, n, i in [(True, "a", 1), (False, "a", 1), (True, "b", 2)]]
    s = summarize(rows)
    assert s["successes"] == 2 and s["by_object"]["a"]["n"] == 2 and s["by_reason"]["missed"] == 1


def test_grasp_cli_writes_episodes_and_summary(tmp_path):
    from simtest.cli import main

    out = tmp_path / "run"
    code = main(["grasp", "--estimator", "oracle", "--opt", "trans_noise_mm=2", "--episodes", "2",
                 "--target", "box_1,can_0", "--width", "96", "--seed", "5", "--out", str(out), "--quiet"])
    assert code == 0
    with (out / "episodes.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert [r["target_name"] for r in rows] == ["box_1", "can_0"]
    assert [int(r["seed"]) for r in rows] == [episode_seed(5, 0), episode_seed(5, 1)]
    assert all(r["reason"] in FAILURE_REASONS for r in rows)
    summary = json.loads((out / "summary.json").read_text())
    assert summary["episodes"] == 2 and 0.0 <= summary["ci95"][0] <= summary["success_rate"] <= summary["ci95"][1]
    assert set(summary["by_object"]) == {"box_1", "can_0"}
    assert summary["config"]["estimator_options"] == {"trans_noise_mm": 2}
    assert "Wilson" in (out / "summary.md").read_text()


def test_results_do_not_depend_on_workers(tmp_path):
    from simtest.envs.runner import GraspRunConfig, run_grasp_episodes

    cfg = GraspRunConfig(estimator="oracle", estimator_options={"trans_noise_mm": 5.0}, episodes=2,
                         targets=("box_1", "can_0"), width=96, height=72, seed=9)
    one = run_grasp_episodes(cfg, progress=False).rows
    two = run_grasp_episodes(GraspRunConfig(**{**cfg.__dict__, "workers": 2}), progress=False).rows
    timing = {"estimate_s", "wall_s"}
    np.testing.assert_equal([{k: v for k, v in r.items() if k not in timing} for r in one],
                            [{k: v for k, v in r.items() if k not in timing} for r in two])  # NaN == NaN
