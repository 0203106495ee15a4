"""The scene layer apart from datasets: a builder made from BuildOptions alone, settling that restores what it
changes, and the dataset side making both sets of options from its config."""

from __future__ import annotations

import ast
import warnings
from pathlib import Path

import mujoco
import numpy as np
import pytest

from simtest.errors import ConfigError
from simtest.generators.build_options import N_OCCLUDERS, BuildOptions, Room, SettleOptions
from simtest.generators.builder import SceneBuilder
from simtest.generators.pipeline import load_objects, prepare_scene
from simtest.generators.scene_spec import sample_scene_spec
from simtest.generators.settle import ROCKING_DAMPING, settle
from simtest.rng import child_rng

ROOT = Path(__file__).resolve().parents[2]


def _model_arrays(model: mujoco.MjModel) -> dict[str, np.ndarray]:
    names = ("body_mass", "body_pos", "body_quat", "geom_size", "geom_type", "geom_group", "geom_friction",
             "geom_pos", "mesh_vert", "light_pos", "light_diffuse", "cam_fovy", "mat_rgba", "dof_damping")
    return {n: np.array(getattr(model, n)) for n in names}


def test_the_scene_layer_names_no_dataset_config():
    for name in ("builder.py", "settle.py", "build_options.py"):
        tree = ast.parse((ROOT / "generators" / name).read_text())
        imported = {n.module for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
        assert "simtest.generators.config" not in imported, name
        assert "GenerateConfig" not in (ROOT / "generators" / name).read_text(), name


def test_build_options_from_a_config_carry_what_building_needs(small_config):
    cfg = small_config.replace(**{"render.profile": "quality", "occlusion.level": "L1", "rig": "wrist",
                                  "scene.table_height": 0.5, "scene.timestep": 0.001})
    opt = cfg.build_options()
    assert opt.camera.width == 160 and opt.camera.height == 120 and np.array_equal(opt.camera.K, cfg.camera.K())
    assert opt.quality == "quality" and opt.occluder_slots == N_OCCLUDERS and opt.panda  # the wrist rig
    assert opt.timestep == 0.001 and opt.room == Room(table_height=0.5)
    assert small_config.build_options().occluder_slots == 0 and not small_config.build_options().panda
    assert cfg.settle_options() == SettleOptions(4.0, 0.01, Room(table_height=0.5))


def test_a_builder_from_options_builds_the_model_a_config_did(small_config):
    """The options the dataset side makes and the config handed in directly (the old way, deprecated) give
    the same model, with what the config asks for: timestep, MSAA and shadows, occluder slots, the camera."""
    cfg = small_config.replace(**{"render.profile": "quality", "occlusion.level": "L2"})
    objects = load_objects(cfg)
    spec = sample_scene_spec(cfg, objects, child_rng(cfg.seed, 0, 0), 0, 0)
    new = SceneBuilder(objects, cfg.build_options()).build(spec)
    with pytest.warns(DeprecationWarning, match="BuildOptions"):
        old_builder = SceneBuilder(objects, cfg)
    old = old_builder.build(spec)
    a, b = _model_arrays(new.model), _model_arrays(old.model)
    assert all(np.array_equal(a[k], b[k]) for k in a)
    m = new.model
    assert m.opt.timestep == cfg.scene.timestep and m.vis.quality.offsamples == 4
    assert m.vis.quality.shadowsize == 2048
    assert mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, "occluder_0") >= 0
    assert new.camera is old_builder.camera or np.array_equal(new.camera.K, old.camera.K)
    with pytest.raises(ConfigError, match="needs BuildOptions"):
        SceneBuilder(objects, {"camera": None})


def test_settle_restores_the_damping_and_flags_it_changes(small_config):
    objects = load_objects(small_config)
    spec = sample_scene_spec(small_config, objects, child_rng(small_config.seed, 0, 0), 0, 0)
    scene = SceneBuilder(objects, small_config.build_options()).build(spec)
    damping, flags = scene.model.dof_damping.copy(), int(scene.model.opt.enableflags)
    assert ROCKING_DAMPING > 0 and not damping.any()  # free bodies: no damping of their own
    result = settle(scene, small_config.settle_options())
    assert result.sim_time > 0
    assert np.array_equal(scene.model.dof_damping, damping)  # exactly, not approximately
    assert int(scene.model.opt.enableflags) == flags


def test_settle_takes_a_scene_section_the_old_way_with_a_warning(small_config):
    objects = load_objects(small_config)
    spec = sample_scene_spec(small_config, objects, child_rng(small_config.seed, 1, 0), 1, 0)
    builder = SceneBuilder(objects, small_config.build_options())
    a, b = builder.build(spec), builder.build(spec)
    new = settle(a, small_config.settle_options())
    with pytest.warns(DeprecationWarning, match="SettleOptions"):
        old = settle(b, small_config.scene)
    assert new == old and np.array_equal(a.data.qpos, b.data.qpos)
    with pytest.raises(ConfigError, match="SettleOptions"):
        settle(a, {"max_time": 1.0})


def test_prepared_scenes_carry_the_camera_of_their_builder(small_config):
    scene, *_ = prepare_scene(small_config, load_objects(small_config), 0)
    assert scene.camera is not None and (scene.camera.width, scene.camera.height) == (160, 120)
    assert np.array_equal(scene.camera.K, small_config.camera.K())


@pytest.mark.parametrize("kwargs, match", [
    ({"quality": "ultra"}, "quality must be one of fast, quality, pbr; got 'ultra'"),
    ({"timestep": 0.0}, "timestep must be > 0 s; got 0.0"),
    ({"occluder_slots": -1}, "occluder_slots must be an integer >= 0; got -1"),
])
def test_build_options_name_the_bad_value(kwargs, match, small_config):
    with pytest.raises(ConfigError, match=match):
        BuildOptions(camera=small_config.build_options().camera, **kwargs)


def test_room_and_settle_options_name_the_bad_value():
    with pytest.raises(ConfigError, match="container must be one of table, bin; got 'tray'"):
        Room(container="tray")
    with pytest.raises(ConfigError, match="max_time must be > 0 s; got -1"):
        SettleOptions(max_time=-1)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        assert Room(table_size=(1, 2)).table_size == (1.0, 2.0)
