"""The grasp scenes' model pool: parked objects are asleep, out of collision and not drawn; scenes on a reused
pool, on a new pool and on a per-structure model (episodes the pool cannot hold) agree; the reset benchmark's
flag check."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

import simtest  # noqa: F401  (GL backend before mujoco)
import mujoco

from simtest.envs.model_cache import PARKED_GROUP, POOL_COPIES, GraspModelCache
from simtest.envs.options import load_objects
from simtest.envs.scene import POOL_DISTRACTORS, build_grasp_scene, scene_config
from simtest.generators.builder import DRAWN_GROUPS, SceneBuilder


@pytest.fixture(scope="module")
def builder():
    return SceneBuilder(load_objects("builtin-small"), scene_config(64, 48), panda_physics=True)


def _cache(builder, pool: bool = True) -> GraspModelCache:
    return GraspModelCache(builder, pool_distractors=POOL_DISTRACTORS, pool=pool)


def _scene(builder, cache, seed: int, target: int, **kw):
    objects = builder.objects
    return build_grasp_scene(builder, objects, target, np.random.default_rng(seed), models=cache, **kw)


def test_parked_objects_are_asleep_out_of_collision_and_hidden(builder):
    cache = _cache(builder)
    scene = _scene(builder, cache, 3, builder.objects.ids[0], n_distractors=1)
    sim = scene.sim
    m, d = sim.model, sim.data
    assert cache.compiles == 1 and len(cache._pool.template.instance_bodies) == POOL_COPIES * len(builder.objects)
    in_play = set(sim.instance_bodies)
    parked = [b for b in cache._pool.template.instance_bodies if b not in in_play]
    parked.append(cache._pool.distractor_bodies[0])  # no occluder in this episode
    assert len(parked) == POOL_COPIES * len(builder.objects) - len(in_play) + 1
    for b in parked:
        g = slice(m.body_geomadr[b], m.body_geomadr[b] + m.body_geomnum[b])
        assert d.tree_asleep[m.body_treeid[b]] >= 0, f"parked body {b} is awake"
        assert not m.geom_contype[g].any() and not m.geom_conaffinity[g].any() and m.body_contype[b] == 0
        assert (m.geom_group[g] == PARKED_GROUP).all() and PARKED_GROUP not in DRAWN_GROUPS
        assert d.xpos[b][2] > 10.0  # far above the room
    for b in in_play:
        assert d.tree_asleep[m.body_treeid[b]] < 0
    # Only the instances in play are annotated; the settled scene's contacts never involve parked geoms.
    assert set(np.unique(sim.geom_instance[sim.geom_instance >= 0])) == set(range(len(in_play)))
    mujoco.mj_step(m, d, 20)
    bodies = m.geom_bodyid[d.contact.geom[:d.ncon]]
    assert d.ncon > 0 and not np.isin(bodies, parked).any()
    assert all(d.tree_asleep[m.body_treeid[b]] >= 0 for b in parked)


def _state(scene) -> tuple:
    sim = scene.sim
    return (sim.data.qpos[np.r_[tuple(np.arange(q, q + 7) for q in sim.instance_qpos)]].copy(),
            sim.data.qpos[sim.panda.arm_qpos].copy(), sim.instance_obj_ids)


def test_reused_pool_new_pool_and_structure_model_agree(builder):
    ids = builder.objects.ids
    cache = _cache(builder)
    for seed in range(3):  # other targets, distractors and the occluder first
        _scene(builder, cache, seed, ids[seed % len(ids)], n_distractors=2, occlusion=seed % 2)
    reused = _state(_scene(builder, cache, 11, ids[1], n_distractors=2, occlusion=1))
    fresh = _state(_scene(builder, _cache(builder), 11, ids[1], n_distractors=2, occlusion=1))
    for a, b in zip(reused, fresh):
        np.testing.assert_array_equal(a, b)
    assert cache.compiles == 1 and cache.reuses == 3 and cache.pool_misses == 0

    # An object three times: the pool holds two copies, so the scene gets a model of its own structure, the
    # same as a cache without a pool builds.
    objects = builder.objects
    rng = np.random.default_rng(5)
    from simtest.envs.scene import sample_grasp_spec

    spec = sample_grasp_spec(builder, objects, ids[0], rng, n_distractors=2)
    triple = dataclasses.replace(spec, objects=tuple(dataclasses.replace(p, obj_id=ids[0]) for p in spec.objects))
    assert len(triple.objects) == 3 and not cache._pool.fits(triple)
    a = cache.build(triple)
    assert cache.pool_misses == 1 and cache.compiles == 2 and a.model is not cache._pool.template.model
    b = _cache(builder, pool=False).build(triple)
    np.testing.assert_array_equal(a.data.qpos, b.data.qpos)
    assert a.model.nbody == b.model.nbody
    # The pool is kept: the next episode it holds reuses it.
    _scene(builder, cache, 12, ids[2], n_distractors=1)
    assert cache.compiles == 2 and cache.reuses == 4


def test_bench_grasp_rejects_a_negative_reset_count(capsys):
    from simtest.cli import main

    assert main(["bench", "grasp", "--resets", "-1"]) == 2
    err = capsys.readouterr().err
    assert "--resets must be >= 0" in err and "-1" in err
