"""The wrist camera's looks and captures: looks change RGB only, pbr observations register with the masks, the
observations of a run are a BOP dataset that ``simtest eval`` scores, failures say why in words."""

from __future__ import annotations

import csv
import importlib.util

import numpy as np
import pytest
from gymnasium.utils import seeding

from simtest.envs.looks import dress_grasp_spec, looks_stream
from simtest.envs.observation import ObservationModel, pbr_seed
from simtest.envs.options import pick_target
from simtest.envs.planner import GraspPlanner
from simtest.envs.scene import build_grasp_scene
from simtest.envs.task import GraspTask
from simtest.errors import ConfigError
from simtest.geometry import Pose


def _instance_map(task: GraspTask) -> np.ndarray:
    """Instance index per pixel of the last capture (-1: not an object)."""
    lut = np.append(task.grasp_scene.sim.geom_instance, -1)
    return lut[task.last_frame.seg]


def test_looks_draw_nothing_from_the_scene_stream():
    """The same scene stream gives the same settled poses, exactly, dressed or plain (both compiled anew)."""
    task = GraspTask(width=96, height=72, episode={"objects": "builtin-small"})
    builder = task._builder("builtin-small")
    objects = builder.objects
    poses = []
    for looks in (False, True):
        rng, _ = seeding.np_random(5)
        scene_rng = rng.spawn(3)[0]
        target = pick_target(objects, None, scene_rng)
        dress = None
        if looks:
            look = looks_stream(scene_rng)
            dress = lambda spec: dress_grasp_spec(spec, objects, look, 0.4)  # noqa: E731
        scene = build_grasp_scene(builder, objects, target, scene_rng, n_distractors=2, looks=dress)
        poses.append(np.array(scene.sim.data.xpos[scene.sim.instance_bodies]))
        if looks:
            spec = scene.sim.spec
            assert spec.table.material is not None or spec.table.pattern != "flat"
    np.testing.assert_array_equal(poses[0], poses[1])


def test_same_seed_same_scene_other_colours():
    """A task with looks and one without: same objects, poses (to the pooled model's rounding) and masks; the
    RGB differs."""
    out = {}
    for looks in (False, True):
        task = GraspTask(width=128, height=96, episode={"objects": "builtin-small", "n_distractors": 2},
                         looks=looks)
        obs = task.reset(seed=11, options={"start": "observe"})
        out[looks] = (task.object_poses_world(), _instance_map(task), obs["rgb"].copy(),
                      task.current_info()["obj_ids"])
        task.close()
    (p0, m0, rgb0, ids0), (p1, m1, rgb1, ids1) = out[False], out[True]
    assert ids0 == ids1
    np.testing.assert_allclose(p0, p1, atol=1e-4)
    assert (m0 >= 0).sum() > 500
    assert (m0 != m1).mean() < 0.002  # a pixel or two on silhouette edges, from the rounding above
    assert (rgb0 != rgb1).any(axis=2).mean() > 0.5


def test_bad_looks_and_profile_named():
    with pytest.raises(ConfigError, match="looks"):
        GraspTask(width=64, height=48, looks="yes")
    with pytest.raises(ConfigError, match="observation profile"):
        ObservationModel(profile="raytraced")


def test_pbr_observation_registers_with_the_masks():
    """Path-traced RGB with the target hidden differs from the full image exactly where the rasterizer's mask
    of the target is: the path tracer and the rasterizer see the same camera and geometry."""
    if importlib.util.find_spec("mitsuba") is None:  # not imported here: simtest picks its variant first
        pytest.skip("the pbr extra (mitsuba) is not installed")
    task = GraspTask(width=128, height=96, episode={"objects": "builtin-small", "target": "box_0"},
                     observation=ObservationModel(profile="pbr"))
    obs = task.reset(seed=2, options={"start": "observe"})
    mask = task.target_mask()
    assert mask.sum() > 300
    geoms = task.target_geoms
    groups = task.model.geom_group[geoms].copy()
    task.model.geom_group[geoms] = 5  # not drawn
    hidden = task._pbr.render(task.data, task.ids.camera, seed=pbr_seed(task._corrupt_rng, 0)).rgb  # same samples
    task.model.geom_group[geoms] = groups
    task.close()
    changed = np.abs(obs["rgb"].astype(int) - hidden.astype(int)).max(axis=2) > 20
    import cv2

    inner = cv2.erode(mask.astype(np.uint8), np.ones((5, 5), np.uint8)).astype(bool)
    grown = cv2.dilate(mask.astype(np.uint8), np.ones((7, 7), np.uint8)).astype(bool)
    assert changed[inner].mean() > 0.95  # the object's pixels are inside the mask ...
    assert changed[grown].sum() / changed.sum() > 0.7  # ... and the changes (besides shadows, reflections) on it


def test_no_feasible_grasp_says_why():
    """An estimate far below the table: every candidate rejected, counted by cause, said in words."""
    task = GraspTask(width=64, height=48, episode={"objects": "builtin-small", "target": "can_0"}, looks=False)
    task.reset(seed=1)
    T = task.object_poses_world()[0]
    res = GraspPlanner().plan(task, task.target_obj, Pose(T[:3, :3], T[:3, 3] - np.array([0.0, 0.0, 0.3])))
    task.close()
    assert res.plan is None and res.reason == "no_feasible_grasp"
    assert sum(res.rejected.values()) == res.n_candidates > 0
    text = res.explain()
    assert text.startswith(f"no_feasible_grasp: {res.n_candidates} candidates, ")
    assert "table clearance" in text or "approach" in text


def test_saved_observations_are_a_dataset(tmp_path):
    """--save-observations: every capture of every episode as a BOP scene that simtest eval scores."""
    from simtest.envs.runner import GraspRunConfig, run_grasp_episodes
    from simtest.evaluation.run import evaluate

    cfg = GraspRunConfig(estimator="oracle", episodes=2, seed=3, objects="builtin-small", width=128, height=96,
                         save_observations=True)
    rep = run_grasp_episodes(cfg, tmp_path / "run", progress=False)
    root = tmp_path / "run" / "observations"
    assert sorted(p.name for p in (root / "test").iterdir()) == ["000000", "000001"]
    assert (root / "camera.json").is_file() and (root / "models" / "models_info.json").is_file()
    ev = evaluate(root, "oracle", split="test", progress=False, out_dir=tmp_path / "eval")
    assert ev.num_images == 4 and not ev.failures  # two captures per episode: at reset and at the view
    with open(tmp_path / "run" / "episodes.csv", newline="") as f:
        header = next(csv.reader(f))
    assert "re_sym_deg" in header and "re_raw_deg" in header and "re_deg" not in header
    assert rep.summary["config"]["looks"] is True


def test_every_failure_says_why():
    """A failed episode without a message of its own gets one from its reason and measurements."""
    from simtest.envs.summary import failure_words

    row = {"reason": "slipped", "target_name": "can_0", "target_obj_id": 1, "lift_height": 0.031, "error": ""}
    assert failure_words(row) == ("slipped: can_0 (obj_id 1) was grasped but not held at least 10 cm up for the "
                                  "whole hold (lifted 3.1 cm)")
    assert failure_words({**row, "error": "no_feasible_grasp: 12 candidates"}) == "no_feasible_grasp: 12 candidates"
    assert failure_words({**row, "reason": "none"}) == ""
