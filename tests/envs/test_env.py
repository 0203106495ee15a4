"""PandaGraspEnv: gymnasium conformance, seeding, observation corruption vs ground truth, the IK step."""

from __future__ import annotations

import numpy as np
import pytest

import simtest.envs  # noqa: F401
from simtest.envs.grasp_env import MAX_STEP_TRANSLATION, PandaGraspEnv
from simtest.errors import ConfigError


def test_registered_and_check_env():
    import gymnasium
    from gymnasium.utils.env_checker import check_env

    env = gymnasium.make("simtest/PandaGrasp-v0", width=96, height=72, render_mode="rgb_array",
                         target="box_1", n_distractors=1)
    check_env(env.unwrapped, skip_render_check=False)
    obs, info = env.reset(seed=1)
    assert obs["rgb"].shape == (72, 96, 3) and obs["rgb"].dtype == np.uint8
    assert obs["depth"].dtype == np.float32 and obs["depth"].max() > 0.1
    assert obs["K"].shape == (3, 3) and obs["K"][0, 0] == pytest.approx(615.0 * 96 / 640)
    assert obs["joint_pos"].shape == (7,) and obs["gripper_width"].shape == (1,)
    assert info["target_name"] == "box_1" and info["T_world_obj"].shape == (2, 4, 4)
    assert not info["is_grasped"] and abs(info["lift_height"]) < 1e-3
    # The camera pose in the base frame agrees with the ground-truth frames in info.
    T_world_cam = info["T_world_base"] @ obs["T_base_cam"]
    np.testing.assert_allclose(T_world_cam, info["T_world_cam"], atol=1e-9)
    np.testing.assert_allclose(np.linalg.inv(T_world_cam) @ info["T_world_obj"][0], info["T_cam_obj"][0],
                               atol=1e-9)
    frame = env.render()
    assert frame.shape == (72, 96, 3) and frame.std() > 5
    env.close()


def _rollout(env, seed, options, actions):
    obs, info = env.reset(seed=seed, options=options)
    out = [(obs, info)]
    for a in actions:
        obs, _, _, _, info = env.step(a)
        out.append((obs, info))
    return out


def test_same_seed_same_observations_and_trajectory(env):
    rng = np.random.default_rng(0)
    actions = rng.uniform(env.action_space.low, env.action_space.high, (4, 7)).astype(np.float32)
    opts = {"n_distractors": 2, "occlusion": "L1", "corruption": {"weather": "fog", "severity": 3},
            "depth_noise": "realsense-d435"}
    a = _rollout(env, 11, opts, actions)
    b = _rollout(env, 11, opts, actions)
    for (oa, ia), (ob, ib) in zip(a, b):
        for k in oa:
            np.testing.assert_array_equal(oa[k], ob[k], err_msg=k)
        np.testing.assert_array_equal(ia["T_world_obj"], ib["T_world_obj"])
        assert ia["target_obj_id"] == ib["target_obj_id"]
    assert a[0][1]["occlusion"]["level"] == "L1" and a[0][1]["occlusion"]["occluded_fraction"] > 0.05
    # Another seed gives another scene.
    c = _rollout(env, 12, opts, actions[:0])
    assert not np.array_equal(a[0][1]["T_world_obj"][0], c[0][1]["T_world_obj"][0])
    # The arm moved as commanded (the commanded TCP goes where the actions say, within IK tolerance).
    assert not np.array_equal(a[0][0]["joint_pos"], a[-1][0]["joint_pos"])


def test_corruption_changes_observations_not_ground_truth(env):
    clean_obs, clean_info = env.reset(seed=5, options={"target": "can_0"})
    obs, info = env.reset(seed=5, options={"target": "can_0", "corruption": {"weather": "fog", "severity": 5},
                                           "depth_noise": "kinect-v1"})
    assert np.abs(obs["rgb"].astype(int) - clean_obs["rgb"]).mean() > 5
    assert not np.array_equal(obs["depth"], clean_obs["depth"])
    for key in ("T_world_obj", "T_cam_obj", "T_world_cam", "q_observe"):
        np.testing.assert_array_equal(info[key], clean_info[key], err_msg=key)
    for key in ("target_obj_id", "is_grasped", "lift_height", "rest_height"):
        assert info[key] == clean_info[key]
    for key in ("K", "T_base_cam", "joint_pos", "joint_vel", "gripper_width"):
        np.testing.assert_array_equal(obs[key], clean_obs[key], err_msg=key)


def test_end_effector_step_moves_the_tcp(env):
    u = env.unwrapped
    env.reset(seed=2, options={"target": "box_1"})
    p0, _ = u.task._diffik.fk(u.task._q_cmd)
    step = np.array([MAX_STEP_TRANSLATION, 0.0, -MAX_STEP_TRANSLATION / 2, 0, 0, 0, 1], dtype=np.float32)
    for _ in range(5):
        env.step(step)
    p1, _ = u.task._diffik.fk(u.task._q_cmd)
    np.testing.assert_allclose(p1 - p0, 5 * step[:3], atol=1.5e-3)
    # Oversized actions are clipped to the per-step limits.
    env.step(np.array([1.0, 0, 0, 0, 0, 0, 1], dtype=np.float32))
    p2, _ = u.task._diffik.fk(u.task._q_cmd)
    assert p2[0] - p1[0] == pytest.approx(MAX_STEP_TRANSLATION, abs=1e-3)


def test_bad_options_name_the_allowed_values(env):
    with pytest.raises(ConfigError, match="allowed"):
        env.reset(seed=0, options={"colour": "red"})
    with pytest.raises(ConfigError, match="L0, L1"):
        env.reset(seed=0, options={"occlusion": "L7"})
    with pytest.raises(ConfigError, match="valid"):
        env.reset(seed=0, options={"depth_noise": "lidar"})
    with pytest.raises(ConfigError, match="names"):
        env.reset(seed=0, options={"target": "teapot"})
    with pytest.raises(ConfigError, match="render_mode"):
        PandaGraspEnv(render_mode="human")


def test_panda_ik_step_option_moves_the_same_way():
    env = PandaGraspEnv(width=96, height=72, n_distractors=0, ik="panda", target="box_1")
    env.reset(seed=2)
    p0, _ = env.task._diffik.fk(env.task._q_cmd)
    for _ in range(3):
        env.step(np.array([0.0, MAX_STEP_TRANSLATION, 0.0, 0, 0, 0, 1], dtype=np.float32))
    p1, _ = env.task._diffik.fk(env.task._q_cmd)
    np.testing.assert_allclose(p1 - p0, [0.0, 3 * MAX_STEP_TRANSLATION, 0.0], atol=1e-3)
    env.close()


def test_the_main_pieces_import_from_the_package():
    import simtest.envs
    from simtest.envs import PandaGraspEnv, run_episode, write_video
    from simtest.envs.episode import run_episode as run_episode_
    from simtest.envs.grasp_env import PandaGraspEnv as Env
    from simtest.io.video import write_video as write_video_

    assert PandaGraspEnv is Env and run_episode is run_episode_ and write_video is write_video_
    assert {"PandaGraspEnv", "run_episode", "write_video"} <= set(simtest.envs.__all__)
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        simtest.envs.nope
