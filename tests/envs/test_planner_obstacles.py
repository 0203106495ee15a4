"""The grasp planner's obstacle source: the simulator's geometry or only what the camera saw."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest
from scipy.spatial import cKDTree

from simtest.envs.episode import _Monitor, _move_joints
from simtest.envs.planner import GraspPlanner, observed_obstacles
from simtest.envs.runner import GraspRunConfig, run_grasp_episodes
from simtest.errors import ConfigError
from simtest.camera import backproject
from simtest.geometry import Pose


def _observe(env, seed: int, n_distractors: int) -> tuple:
    """Reset, move to the observation configuration and capture: ``(unwrapped env, obs, info)``."""
    u = env.unwrapped
    u.reset(seed=seed, options={"n_distractors": n_distractors, "target": "box_1"})
    _move_joints(u, u.q_observe, _Monitor(u, None))
    return u, u.capture(), u.current_info()


def _instance_points(u, obs: dict, instance: int) -> np.ndarray:
    """World points (m) of the clean depth pixels showing ``instance``, more than 5 mm above the table."""
    frame = u.last_frame
    geoms = np.flatnonzero(u.grasp_scene.sim.geom_instance == instance)
    T_world_cam = u.T_world_base @ Pose.from_matrix(obs["T_base_cam"])
    pts = backproject(frame.depth, obs["K"], np.isin(frame.seg, geoms)) @ T_world_cam.R.T + T_world_cam.t
    return pts[pts[:, 2] > u.grasp_scene.table_height + 0.005]


def test_planner_obstacles_option_validates(tmp_path):
    from simtest.cli import main

    with pytest.raises(ConfigError, match=r"planner_obstacles.*sim, observed.*'lidar'"):
        run_grasp_episodes(GraspRunConfig(planner_obstacles="lidar", episodes=1, width=64, height=48),
                           progress=False)
    with pytest.raises(ConfigError, match="'voxels'"):
        GraspPlanner(obstacles="voxels")
    with pytest.raises(SystemExit) as exc:
        main(["grasp", "--estimator", "oracle", "--planner-obstacles", "lidar", "--out", str(tmp_path / "x")])
    assert exc.value.code == 2


def test_observed_needs_the_cloud(env):
    u, _, info = _observe(env, seed=3, n_distractors=0)
    T_world_obj = Pose.from_matrix(info["T_world_obj"][0])
    with pytest.raises(ConfigError, match="obstacle_points"):
        GraspPlanner(obstacles="observed").plan(u, u.target_obj, T_world_obj)


def test_observed_cloud_excludes_target_and_includes_distractor(env):
    for seed in range(20):  # a scene where the distractor is in view
        u, obs, info = _observe(env, seed, n_distractors=1)
        distractor = _instance_points(u, obs, 1)
        if len(distractor) >= 20:
            break
    else:
        pytest.fail("no scene with a visible distractor in 20 seeds")
    target = _instance_points(u, obs, 0)
    assert len(target) >= 20
    gt = Pose.from_matrix(info["T_world_obj"][0])
    cloud = observed_obstacles(u, obs, u.target_obj, gt)
    assert len(cloud) > 0 and (cloud[:, 2] > u.grasp_scene.table_height + 0.005).all()
    tree = cKDTree(cloud)
    near_target, _ = tree.query(target)
    assert near_target.min() > 0.002  # the target's points are gone
    near_distractor, _ = tree.query(distractor)
    assert np.mean(near_distractor < 0.008) > 0.9  # the distractor's points are there (thinned to 4 mm voxels)
    surface = np.asarray(u.target_obj.surface_cloud(4000)[0]) @ gt.R.T + gt.t
    assert cKDTree(surface).query(cloud)[0].min() >= 0.01 - 1e-9

    # The target is removed where the estimate puts it: a pose 20 cm off leaves its points in the cloud.
    off = Pose(gt.R, gt.t + np.array([0.0, 0.2, 0.0]))
    near_target, _ = cKDTree(observed_obstacles(u, obs, u.target_obj, off)).query(target)
    assert np.mean(near_target < 0.008) > 0.9


def test_observed_obstacle_points_reject_candidates(env):
    u, obs, info = _observe(env, seed=3, n_distractors=0)
    T_world_obj = Pose.from_matrix(info["T_world_obj"][0])
    planner = GraspPlanner(obstacles="observed")
    free = planner.plan(u, u.target_obj, T_world_obj, obstacle_points=observed_obstacles(u, obs, u.target_obj,
                                                                                          T_world_obj))
    assert free.plan is not None and free.reason == "ok"
    # A block of points from 2 cm above the target's top up to 20 cm: every approach passes through it.
    top = float((np.asarray(u.target_obj.vertices) @ T_world_obj.R.T + T_world_obj.t)[:, 2].max())
    g = np.arange(-0.2, 0.2, 0.01)
    x, y, z = np.meshgrid(g, g, np.arange(0.02, 0.2, 0.01), indexing="ij")
    slab = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1) + [T_world_obj.t[0], T_world_obj.t[1], top]
    blocked = planner.plan(u, u.target_obj, T_world_obj, obstacle_points=slab)
    assert blocked.plan is None and blocked.reason == "no_feasible_grasp"
    sim = GraspPlanner().plan(u, u.target_obj, T_world_obj, obstacle_points=slab)
    assert sim.plan is not None  # sim mode ignores the points


def test_observed_runs_end_to_end_and_is_recorded(tmp_path):
    from simtest.cli import main

    out = tmp_path / "run"
    code = main(["grasp", "--estimator", "oracle", "--episodes", "1", "--target", "box_1", "--distractors", "1",
                 "--planner-obstacles", "observed", "--width", "64", "--seed", "2", "--out", str(out), "--quiet"])
    assert code == 0
    with (out / "episodes.csv").open() as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == 1 and rows[0]["reason"] == "none"  # the oracle grasps the box with observed obstacles
    assert rows[0]["planner_obstacles"] == "observed"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["planner_obstacles"] == "observed" and summary["config"]["planner_obstacles"] == "observed"
    assert "planner obstacles observed" in (out / "summary.md").read_text()
