"""Dressed grasp episodes on one kept model (looks slots): a reset writes the episode's textures, materials and
lights into the pool instead of compiling; its images match a model compiled from the dressed spec; the same
seed gives the same images on a reused and a new pool; looks that do not fit the slots get a model of their
own, and a texture of the wrong size is refused before anything is written."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import simtest  # noqa: F401  (GL backend before mujoco)
import mujoco

from simtest.envs.looks import dress_grasp_spec, looks_stream
from simtest.envs.looks_slots import LIGHT_SLOTS, SlotMismatch, poolable, write_looks
from simtest.envs.model_cache import LOOKS_KEY, GraspModelCache
from simtest.envs.options import load_objects
from simtest.envs.scene import POOL_DISTRACTORS, sample_grasp_spec, scene_config
from simtest.envs.task import GraspTask
from simtest.generators.builder import SceneBuilder

EPISODE = {"objects": "builtin-small", "target": None, "n_distractors": 2}


def _dressed(builder: SceneBuilder, seed: int, occlusion: int = 1):
    rng = np.random.default_rng(seed)
    objects = builder.objects
    spec = sample_grasp_spec(builder, objects, objects.ids[seed % len(objects.ids)], rng, n_distractors=2,
                             occlusion=occlusion)
    return dress_grasp_spec(spec, objects, looks_stream(rng), float(builder.options.room.table_height))


def test_dressed_resets_reuse_the_pool_and_match_a_compiled_model():
    pooled = GraspTask(width=96, height=72, episode=EPISODE, looks=True)
    compiled = GraspTask(width=96, height=72, episode=EPISODE, looks=True, model_pool=False)
    images = {}
    for seed in (1, 2, 3):
        a = pooled.reset(seed=seed, options={"occlusion": "L1"} if seed == 2 else None)["rgb"]
        b = compiled.reset(seed=seed, options={"occlusion": "L1"} if seed == 2 else None)["rgb"]
        images[seed] = a.copy()
        # The same looks: only the settled poses' rounding (about 1e-7 m) moves a few pixels by a grey level or so.
        diff = np.abs(a.astype(int) - b.astype(int)).max(axis=2)
        assert (diff > 3).mean() < 0.002, f"seed {seed}: {(diff > 3).mean():.4f} of the pixels differ"
        if seed > 1:
            assert pooled.models.uploads, "a reused pool writes the episode's textures"
    models = pooled.models
    assert models._pool.key == LOOKS_KEY
    assert models.compiles == 1 and models.reuses == 2 and models.pool_misses == 0
    assert compiled.models.compiles == 3
    assert not np.array_equal(images[1], images[3])  # other looks
    # The same seed on a reused pool and on a new one: the same image.
    again = pooled.reset(seed=1)["rgb"]
    np.testing.assert_array_equal(again, images[1])
    fresh = GraspTask(width=96, height=72, episode=EPISODE, looks=True)
    np.testing.assert_array_equal(fresh.reset(seed=3)["rgb"], images[3])
    for t in (pooled, compiled, fresh):
        t.close()


def test_lights_fill_the_first_slots_and_the_rest_are_off():
    builder = SceneBuilder(load_objects("builtin-small"), scene_config(64, 48), panda_physics=True)
    cache = GraspModelCache(builder, pool_distractors=POOL_DISTRACTORS)
    for seed in range(4):
        spec = _dressed(builder, seed)
        if seed % 2:  # the room lit by lights instead of an environment
            spec = dataclasses.replace(spec, environment=None)
        assert poolable(spec)
        scene = cache.build(spec)
        m = scene.model
        ambient, lights = builder.light_values(spec)
        ids = [mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_LIGHT, f"light_{k}") for k in range(LIGHT_SLOTS)]
        assert m.nlight == LIGHT_SLOTS and [bool(m.light_active[i]) for i in ids] == \
            [k < len(lights) for k in range(LIGHT_SLOTS)]
        for i, light in zip(ids, lights):
            assert m.light_type[i] == int(light.type)
            np.testing.assert_allclose(m.light_diffuse[i], light.diffuse)
            np.testing.assert_allclose(scene.data.light_xpos[i], light.position, atol=1e-12)
        np.testing.assert_allclose(m.vis.headlight.ambient, ambient)
    assert cache.compiles == 1 and cache.reuses == 3


def test_looks_that_do_not_fit_get_a_model_and_a_wrong_size_writes_nothing():
    builder = SceneBuilder(load_objects("builtin-small"), scene_config(64, 48), panda_physics=True)
    cache = GraspModelCache(builder, pool_distractors=POOL_DISTRACTORS)
    spec = _dressed(builder, 5)
    cache.build(spec)
    pattern = dataclasses.replace(spec, table=dataclasses.replace(spec.table, material=None, pattern="checker"))
    assert not poolable(pattern)
    scene = cache.build(pattern)
    assert scene.model is not cache._pool.template.model and cache.compiles == 2
    # Maps of another size than the slots': refused before any texture, material or light is written.
    pool = cache._pool
    other = SceneBuilder(builder.objects, dataclasses.replace(builder.options, texture_size=64), panda_physics=True)
    before = pool.template.model.tex_data.copy(), pool.template.model.mat_texrepeat.copy()
    with pytest.raises(SlotMismatch, match="table_tex"):
        write_looks(pool.template, _dressed(builder, 6), [f"obj_{k}_mat" for k in range(3)], other)
    np.testing.assert_array_equal(pool.template.model.tex_data, before[0])
    np.testing.assert_array_equal(pool.template.model.mat_texrepeat, before[1])
