"""PandaGraspEnv as RL clients use it: bad actions, many resets (model reuse, memory), vector envs, torch."""

from __future__ import annotations

import ctypes
import os
import subprocess
import sys
import textwrap

import gymnasium
import numpy as np
import pytest

import simtest.envs  # noqa: F401  (registers the env)
from simtest.errors import ConfigError

W, H = 64, 48
KW = {"width": W, "height": H, "n_distractors": 0, "target": "box_1"}


def _make(**kw):
    return gymnasium.make("simtest/PandaGrasp-v0", **{**KW, **kw})


def _assert_same(obs_a: dict, obs_b: dict) -> None:
    for k in obs_a:
        np.testing.assert_array_equal(obs_a[k], obs_b[k], err_msg=k)


def _rss_mb() -> float:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2 ** 20


def _run(script: str, timeout: float = 240.0) -> subprocess.CompletedProcess:
    """Run ``script`` in a fresh interpreter (a regression that hangs fails on the timeout, not the suite)."""
    return subprocess.run([sys.executable, "-c", textwrap.dedent(script)], capture_output=True, text=True,
                          timeout=timeout, env={**os.environ, "PYTHONFAULTHANDLER": "1"})


def test_bad_action_is_rejected_and_changes_nothing():
    a, b = _make(), _make()
    a.reset(seed=5)
    b.reset(seed=5)
    move = np.array([0.01, 0.0, -0.01, 0.0, 0.0, 0.05, 0.5], np.float32)
    a.step(move)
    b.step(move)
    nan = move.copy()
    nan[2] = np.nan
    inf = move.copy()
    inf[6] = -np.inf
    for bad, match in ((nan, r"action\[2\] \(dz\) = nan"), (inf, r"action\[6\] \(g\) = -inf"),
                       (move[:6], r"shape \(7,\).*got shape \(6,\)"), (move[None], r"got shape \(1, 7\)"),
                       ("up", "7 finite numbers")):
        with pytest.raises(ConfigError, match=match) as exc:
            a.step(bad)
        assert isinstance(exc.value, ValueError) and "Box(7) [dx, dy, dz, rx, ry, rz, g]" in str(exc.value)
    # The env keeps working, exactly as if the bad calls had not been made.
    for _ in range(2):
        oa, ra, ta, ua, ia = a.step(move)
        ob, rb, tb, ub, ib = b.step(move)
        _assert_same(oa, ob)
        assert (ra, ta, ua, ia["sim_time"]) == (rb, tb, ub, ib["sim_time"])
    np.testing.assert_array_equal(a.unwrapped.data.qpos, b.unwrapped.data.qpos)
    np.testing.assert_array_equal(a.unwrapped.data.ctrl, b.unwrapped.data.ctrl)
    assert np.isfinite(a.unwrapped.data.ctrl).all()
    a.close()
    b.close()


def test_resets_reuse_the_model_and_stay_deterministic():
    """One model (the object set's pool) serves every episode of an object set: other targets, distractors,
    with and without the occluder. The same seed gives identical observations and steps on a fresh env. (The
    plain look; the looks slots: tests/envs/test_looks_slots.py.)"""
    env = _make(render_mode="rgb_array", render_width=80, render_height=60, objects="builtin-small",
                target=None, n_distractors=2, looks=False)
    u = env.unwrapped
    env.reset(seed=1, options={"occlusion": "L1"})
    env.step(np.zeros(7, np.float32))
    env.render()
    model, renderer, tp = u.model, u.task._renderer, u.task._tp_renderer
    reused, info_reused = env.reset(seed=2, options={"occlusion": "L1"})
    assert u.model is model and u.task._renderer is renderer and renderer._con is not None
    env.render()
    assert u.task._tp_renderer is tp
    targets = {info_reused["target_name"]}
    for seed in range(3, 9):  # random targets and distractors, no occluder: still the same model
        _, info = env.reset(seed=seed)
        targets.add(info["target_name"])
    assert len(targets) > 1 and u.model is model and renderer._con is not None
    again, info_again = env.reset(seed=9)
    assert u.task.models.compiles == 1 and u.task.models.reuses == 8 and u.task.models.pool_misses == 0

    fresh = _make(render_mode="rgb_array", render_width=80, render_height=60, objects="builtin-small",
                  target=None, n_distractors=2, looks=False)
    obs, info = fresh.reset(seed=2, options={"occlusion": "L1"})
    _assert_same(obs, reused)
    assert info["occlusion"] == info_reused["occlusion"]
    np.testing.assert_array_equal(info["T_world_obj"], info_reused["T_world_obj"])
    obs, info = fresh.reset(seed=9)
    _assert_same(obs, again)
    assert info["obj_ids"] == info_again["obj_ids"]
    np.testing.assert_array_equal(fresh.render(), env.render())
    for _ in range(3):
        oa, ra, ta, _, ia = env.step(np.full(7, 0.01, np.float32))
        ob, rb, tb, _, ib = fresh.step(np.full(7, 0.01, np.float32))
        _assert_same(oa, ob)
        assert (ra, ta, ia["is_grasped"]) == (rb, tb, ib["is_grasped"])
        np.testing.assert_array_equal(ia["T_world_obj"], ib["T_world_obj"])
    np.testing.assert_array_equal(u.data.qpos, fresh.unwrapped.data.qpos)
    env.close()
    fresh.close()
    assert renderer._con is None and tp._con is None  # close() frees the renderers


def test_physics_only_envs_keep_one_model_per_structure():
    """Without images every step the env compiles per structure (parked objects would slow its physics),
    unless the pool is asked for; a bad ``model_pool`` names the allowed values (plain look, as above)."""
    env = _make(objects="builtin-small", target="box_0", observe_every_step=False, looks=False)
    env.reset(seed=0)
    env.reset(seed=1, options={"target": "can_0"})
    models = env.unwrapped.task.models
    assert not models.use_pool and models.compiles == 2 and models.reuses == 0
    env.close()
    env = _make(objects="builtin-small", target="box_0", observe_every_step=False, model_pool=True, looks=False)
    env.reset(seed=0)
    env.reset(seed=1, options={"target": "can_0"})
    assert env.unwrapped.task.models.compiles == 1 and env.unwrapped.task.models.reuses == 1
    env.close()
    with pytest.raises(ConfigError, match="model_pool must be True, False or None"):
        _make(model_pool="yes")


def _trimmed_rss_mb() -> float:
    """Resident memory (MB) after glibc returns its free pages, so that heap fragmentation does not read as growth."""
    ctypes.CDLL("libc.so.6").malloc_trim(0)
    return _rss_mb()


def test_memory_stays_bounded_over_resets():
    """Resident memory stays flat over resets (reused and rebuilt models) in the plain look, once every object of
    the set has been loaded: 30 more resets after a 20-reset warm-up add little."""
    env = _make(objects="builtin-small", n_distractors=1, target=None, looks=False)  # random targets: rebuilt models

    def resets(seeds) -> None:
        for seed in seeds:
            env.reset(seed=seed, options={"target": "box_0", "n_distractors": 0} if seed % 3 else None)

    resets(range(20))
    rss_warm = _trimmed_rss_mb()
    resets(range(20, 50))
    rss_after = _trimmed_rss_mb()
    env.close()
    assert rss_after < rss_warm + 60.0, f"RSS grew from {rss_warm:.0f} MB to {rss_after:.0f} MB over 30 resets"


def test_memory_stays_bounded_over_resets_with_looks():
    """With the looks on, every reset compiles a dressed model whose textures differ in size, so resident memory
    swings by tens of MB from reset to reset; its peak does not climb: the highest reading of resets 60-100 stays
    within 60 MB of the highest of resets 20-60."""
    env = _make(objects="builtin-small", n_distractors=1, target=None)

    def peak(seeds) -> float:
        high = 0.0
        for seed in seeds:
            env.reset(seed=seed, options={"target": "box_0", "n_distractors": 0} if seed % 3 else None)
            high = max(high, _trimmed_rss_mb())
        return high

    peak(range(20))
    warm, late = peak(range(20, 60)), peak(range(60, 100))
    env.close()
    assert late < warm + 60.0, f"peak RSS grew from {warm:.0f} MB to {late:.0f} MB over 40 resets"


def test_async_vector_env_with_spawn_context():
    envs = gymnasium.make_vec("simtest/PandaGrasp-v0", num_envs=2, vectorization_mode="async",
                              vector_kwargs={"context": "spawn"}, **KW)
    try:
        obs, info = envs.reset(seed=0)
        assert obs["rgb"].shape == (2, H, W, 3) and (obs["depth"] > 0).any()
        obs, reward, terminated, truncated, info = envs.step(np.zeros((2, 7), np.float32))
        assert obs["joint_pos"].shape == (2, 7) and reward.shape == (2,)
    finally:
        envs.close()


def test_fork_after_render_raises_a_clear_error():
    """Forked workers of a process that has rendered raise RenderError (instead of hanging in GL)."""
    res = _run(f"""
        import gymnasium, simtest.envs
        from simtest.errors import RenderError
        kw = {KW!r}
        env = gymnasium.make("simtest/PandaGrasp-v0", **kw)
        env.reset(seed=0)  # this process now has a GL context
        envs = gymnasium.make_vec("simtest/PandaGrasp-v0", num_envs=2, vectorization_mode="async",
                                  vector_kwargs={{"context": "fork"}}, **kw)
        try:
            envs.reset(seed=0)
        except RenderError as exc:
            print("RenderError:", exc)
        finally:
            envs.close(terminate=True)
        """)
    assert res.returncode == 0, res.stderr[-2000:]
    assert "RenderError: this process was forked" in res.stdout, res.stdout + res.stderr[-2000:]
    assert "vector_kwargs={'context': 'spawn'}" in res.stdout


def test_torch_compiler_stack_imports_after_rendering():
    """torch imported, then an EGL render, then ``import torch._dynamo``: the renderer imported it first."""
    pytest.importorskip("torch")
    res = _run("""
        import sys
        import torch
        import mujoco
        import simtest.render.gl
        from simtest.render.rasterizer import Renderer
        xml = "<mujoco><worldbody><camera name='c' pos='0 0 1'/><geom type='sphere' size='.1'/></worldbody></mujoco>"
        model = mujoco.MjModel.from_xml_string(xml)
        data = mujoco.MjData(model)
        mujoco.mj_forward(model, data)
        with Renderer(model, 32, 24) as r:
            assert r.render(data, "c").seg.max() == 0
        assert "torch._dynamo" in sys.modules  # imported before the first GL context
        import torch._dynamo  # noqa: F401
        print("ok", simtest.render.gl.backend())
        """)
    assert res.returncode == 0, res.stderr[-2000:]
    assert res.stdout.startswith("ok")


def test_simtest_does_not_import_torch():
    res = _run("""
        import sys
        import simtest.envs.grasp_env, simtest.render.rasterizer, simtest.render.gl
        assert "torch" not in sys.modules, "simtest imported torch"
        print("ok")
        """)
    assert res.returncode == 0 and res.stdout.strip() == "ok", res.stderr[-2000:]
