"""PandaGraspEnv with a simulated stereo depth sensor: the observation's depth is the sensed depth (holes,
errors of a few mm at grasping range), the exact depth stays in ``depth_exact``, the same seed gives the same
bytes, and turning the sensor on changes nothing but the observation's depth."""

from __future__ import annotations

import csv
import dataclasses
import math

import numpy as np
import pytest

from simtest.envs.episode import run_episode
from simtest.envs.grasp_env import DEPTH_SENSORS, PandaGraspEnv
from simtest.envs.observation import ObservationModel
from simtest.errors import ConfigError
from simtest.estimators.oracle import OracleEstimator

W, H = 160, 120
ZERO = np.array([0.0, 0.0, -0.01, 0.0, 0.0, 0.0, 1.0])


def _env(sensor: str) -> PandaGraspEnv:
    return PandaGraspEnv(width=W, height=H, target="box_1", n_distractors=1, start="observe",
                         observation=ObservationModel(depth_sensor=sensor))


def _rollout(env: PandaGraspEnv, seed: int, steps: int = 3):
    obs, info = env.reset(seed=seed)
    out = [(obs, info, 0.0, env.depth_exact.copy())]
    for _ in range(steps):
        obs, reward, _, _, info = env.step(ZERO)
        out.append((obs, info, reward, env.depth_exact.copy()))
    return out


@pytest.fixture(scope="module")
def rollouts():
    sensed, exact = _env("d435-stereo"), _env("none")
    try:
        yield _rollout(sensed, 2), _rollout(sensed, 2), _rollout(exact, 2)
    finally:
        sensed.close()
        exact.close()


def test_sensed_depth_has_holes_and_small_errors_at_grasping_range(rollouts):
    sensed, _, _ = rollouts
    for obs, _, _, exact in sensed:
        depth = obs["depth"]
        assert depth.dtype == np.float32 and depth.shape == (H, W)
        assert not np.array_equal(depth, exact)
        assert ((depth == 0) & (exact > 0)).any()  # invalid pixels where the scene has depth
        near = (exact > 0.3) & (exact < 0.6)
        ok = near & (depth > 0)
        assert near.sum() > 0.2 * depth.size and ok.sum() > 0.5 * near.sum(), (near.sum(), ok.sum())
        err = np.abs(depth[ok] - exact[ok])
        assert np.median(err) < 0.01 and np.percentile(err, 90) < 0.04, (np.median(err), np.percentile(err, 90))


def test_same_seed_same_bytes(rollouts):
    a, b, _ = rollouts
    for (oa, _, _, ea), (ob, _, _, eb) in zip(a, b):
        assert oa["depth"].tobytes() == ob["depth"].tobytes()
        assert oa["rgb"].tobytes() == ob["rgb"].tobytes() and ea.tobytes() == eb.tobytes()


def test_the_sensor_changes_only_the_observation_depth(rollouts):
    sensed, _, plain = rollouts
    for (os_, is_, rs, es), (op, ip, rp, ep) in zip(sensed, plain):
        assert rs == rp
        assert es.tobytes() == ep.tobytes() and op["depth"].tobytes() == ep.tobytes()
        for key in ("rgb", "K", "T_base_cam", "joint_pos", "joint_vel", "gripper_width"):
            assert np.array_equal(os_[key], op[key]), key
        assert set(is_) == set(ip)
        for key, value in ip.items():
            assert np.array_equal(np.asarray(is_[key]), np.asarray(value)) if key != "occlusion" else \
                is_[key] == value, key


def _comparable(result) -> dict:
    row = dataclasses.asdict(result)
    for key in ("estimate_s", "wall_s", "frames", "trace", "traceback"):
        row.pop(key, None)
    return {k: ("nan" if isinstance(v, float) and math.isnan(v) else v) for k, v in row.items()}


def test_oracle_episode_is_unchanged_by_the_sensor():
    results = []
    for sensor in ("none", "d435-stereo"):
        env = PandaGraspEnv(width=96, height=72, n_distractors=0, observation=ObservationModel(depth_sensor=sensor))
        try:
            results.append(_comparable(run_episode(env, OracleEstimator(), seed=3, options={"target": "box_1"})))
        finally:
            env.close()
    assert results[0] == results[1]
    assert results[0]["success"] and results[0]["reason"] == "none"


def test_unknown_sensor_names_the_presets(tmp_path):
    assert DEPTH_SENSORS == ("none", "d435-stereo", "passive-stereo")
    with pytest.raises(ConfigError, match="d435-stereo") as err:
        ObservationModel(depth_sensor="kinect")
    assert "passive-stereo" in str(err.value) and "none" in str(err.value)
    from simtest.envs.runner import GraspRunConfig, run_grasp_episodes

    with pytest.raises(ConfigError, match="passive-stereo"):
        run_grasp_episodes(GraspRunConfig(episodes=1, depth_sensor="kinect"), str(tmp_path / "run"))
    assert not (tmp_path / "run" / "episodes.csv").exists()


def test_grasp_cli_depth_sensor(tmp_path):
    from simtest.cli import main

    out = tmp_path / "run"
    code = main(["grasp", "--estimator", "oracle", "--episodes", "1", "--target", "box_1", "--width", "96",
                 "--depth-sensor", "d435-stereo", "--out", str(out), "--quiet"])
    assert code == 0
    with (out / "episodes.csv").open() as f:
        assert len(list(csv.DictReader(f))) == 1
    assert "depth sensor d435-stereo" in (out / "summary.md").read_text()
