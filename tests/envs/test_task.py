"""The grasp task: deterministic resets, the planner and episodes on the task alone, the env a thin adapter."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from simtest.envs.episode import run_episode
from simtest.envs.grasp_env import PandaGraspEnv
from simtest.envs.observation import ObservationModel
from simtest.envs.planner import GraspPlanner
from simtest.envs.task import GraspTask, as_task
from simtest.errors import ConfigError
from simtest.estimators.oracle import OracleEstimator
from simtest.geometry import Pose

W, H = 96, 72


@pytest.fixture(scope="module")
def task():
    t = GraspTask(width=W, height=H, episode={"objects": "builtin-small", "n_distractors": 1})
    yield t
    t.close()


def _same_obs(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for k in a:
        np.testing.assert_array_equal(a[k], b[k], err_msg=k)


def test_reset_is_deterministic_per_seed(task):
    first = task.reset(seed=7)
    info = task.current_info()
    other = GraspTask(width=W, height=H, episode={"objects": "builtin-small", "n_distractors": 1})
    try:
        again = other.reset(seed=7)
        _same_obs(first, again)
        np.testing.assert_array_equal(info["T_world_obj"], other.current_info()["T_world_obj"])
        assert info["target_name"] == other.target_obj.name
        other.reset(seed=8)
        assert not np.array_equal(other.current_info()["T_world_obj"], info["T_world_obj"])
    finally:
        other.close()
    _same_obs(task.reset(seed=7), first)  # the same task, reused model: the same scene again


def test_planner_works_from_the_task_alone(task):
    task.reset(seed=3, options={"target": "box_0", "n_distractors": 0, "start": "observe"})
    obj = task.target_obj
    T_world_obj = Pose.from_matrix(task.current_info()["T_world_obj"][task.grasp_scene.target_instance])
    result = GraspPlanner().plan(task, obj, T_world_obj)
    assert result.reason == "ok" and result.plan is not None
    assert 0 <= result.plan.index < result.n_candidates
    # The task advances and re-observes at any time; a new capture follows the arm.
    before = task.observe()["T_base_cam"]
    task.data.ctrl[task.ids.arm_actuators] = result.plan.q_above
    task.advance(1.0)
    task.sync_command()
    assert not np.allclose(task.observe()["T_base_cam"], before)


def _comparable(result) -> dict:
    row = result.to_row()
    for k in ("wall_s", "estimate_s"):
        row.pop(k)
    return {k: ("nan" if isinstance(v, float) and math.isnan(v) else v) for k, v in row.items()}


def test_env_is_a_thin_adapter_over_its_task():
    env = PandaGraspEnv(width=W, height=H, objects="builtin-small", n_distractors=0)
    try:
        assert as_task(env) is env.task and env.model is None
        by_env = run_episode(env, OracleEstimator(), seed=3, options={"target": "can_0"})
        assert env.model is env.task.model and env.data is env.task.data  # the env reads the task's physics
        by_task = run_episode(env.task, OracleEstimator(), seed=3, options={"target": "can_0"})
    finally:
        env.close()
    alone = GraspTask(width=W, height=H, episode={"objects": "builtin-small", "n_distractors": 0})
    try:
        by_own_task = run_episode(alone, OracleEstimator(), seed=3, options={"target": "can_0"})
    finally:
        alone.close()
    assert _comparable(by_env) == _comparable(by_task) == _comparable(by_own_task)
    assert by_env.success and by_env.reason == "none"


def test_env_steps_through_its_task():
    """The env's step is the task's control step plus the observation: the same bytes either way."""
    env = PandaGraspEnv(width=W, height=H, objects="builtin-small", n_distractors=0, target="box_0")
    task = GraspTask(width=W, height=H, episode={"objects": "builtin-small", "n_distractors": 0,
                                                 "target": "box_0"})
    try:
        obs_env, _ = env.reset(seed=2)
        _same_obs(obs_env, task.reset(seed=2))
        action = np.array([0.01, -0.005, -0.01, 0.02, 0.0, -0.03, 0.5], np.float32)
        for _ in range(3):
            obs_env, reward, terminated, truncated, info = env.step(action)
            task.control(action.astype(np.float64))
            _same_obs(obs_env, task.observe())
            assert reward == float(task.is_lifted()) and not terminated and not truncated
        np.testing.assert_array_equal(env.task.data.qpos, task.data.qpos)
    finally:
        env.close()
        task.close()


def test_old_keywords_move_to_the_observation_model():
    with pytest.warns(DeprecationWarning, match="ObservationModel"):
        env = PandaGraspEnv(width=W, height=H, depth_sensor="d435-stereo", depth_noise="realsense-d435")
    assert env.task.observation == ObservationModel(depth_sensor="d435-stereo", depth_noise="realsense-d435")
    assert env.depth_sensor == "d435-stereo" and env.config.corruption is not None
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        PandaGraspEnv(width=W, height=H, observation=ObservationModel(corruption={"weather": "fog"}))
    given = GraspTask(width=W, height=H)
    assert PandaGraspEnv(task=given).task is given
    with pytest.raises(ConfigError, match="either task= or"):
        PandaGraspEnv(task=given, width=W)
    with pytest.raises(ConfigError, match="unknown PandaGraspEnv keyword"):
        PandaGraspEnv(widht=W)
    with pytest.raises(ConfigError, match="GraspTask or a PandaGraspEnv"):
        as_task(object())
    with pytest.raises(ConfigError, match="call reset"):
        given.observe()


def test_moved_runner_names_warn_and_still_work():
    import simtest.envs.runner as runner
    from simtest.envs.noise_sweep import noise_sweep
    from simtest.io.video import write_video
    from simtest.metrics.intervals import wilson_interval

    for name, new in (("wilson_interval", wilson_interval), ("write_video", write_video),
                      ("noise_sweep", noise_sweep)):
        with pytest.warns(DeprecationWarning, match=f"runner.{name} moved"):
            assert getattr(runner, name) is new
