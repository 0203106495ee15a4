"""``simtest bench grasp``: grasp-env speed as a ratio against raw ``mj_step`` of the same model, same run.

* **Step overhead**: wall time per physics step of :meth:`PandaGraspEnv.step` without image observations
  (``observe_every_step=False``, so on a model of the episode's own objects, not the pool: differential IK,
  servo commands, 25 physics steps, kinematics, state observation and ground-truth ``info``) against
  ``mujoco.mj_step`` of the same model from the same state with the same controls. Target: at most 20 %
  overhead.
  The wall-clock ratio includes whatever else the machine runs; the env's own work (IK, observation,
  ``info``), timed outside ``mj_step`` in the same loop, is reported too.
* **Steps with images**: env steps/s when every step renders the wrist RGB-D observation (for reference).
* **Pool vs per-structure model**: env steps/s, without and with images, of the same episode on the object
  set's pool model (every object of the set in the model, the unused ones parked asleep) and on a model of the
  episode's objects only, timed in interleaved rounds (the fastest of each kept); their ratio is what the pool
  costs in stepping (target: >= 0.95).
* **Episode wall time**: :func:`simtest.envs.episode.run_episode` with the zero-noise oracle (reset, scene
  build and settling included). Target: at most 10 s per episode.
* **Resets**: wall time of :meth:`PandaGraspEnv.reset` (scene sampling, model reuse or compilation, settling,
  observation view, first render) with the object set unchanged: a fixed structure (one target, no distractors)
  and the default env (random targets and two random distractors from the whole set); median and 95th
  percentile (target: median <= 50 ms). Each object's grasp set and resting pose, computed once per process on
  first use (about 1 s per object), are computed before the timing. The process's resident size (RSS) after
  5, 50, 100, 500, ... random resets, and its growth from 5 resets to the last (target: <= 100 MB over 500
  resets). Reset benchmarks run first, in a process that has not rendered yet, so the RSS figures are those of
  one env.
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass, field

import numpy as np

import simtest  # noqa: F401
import mujoco

__all__ = ["GraspBench", "ResetBench", "bench_grasp", "bench_resets", "bench_pool_steps", "RSS_CHECKPOINTS"]

#: Resets after which the resident size is recorded (those up to the number of resets run).
RSS_CHECKPOINTS = (5, 50, 100, 500, 1000, 2000)


@dataclass
class ResetBench:
    """Results of :func:`bench_resets`: reset wall times (s) and resident sizes (MB).

    Attributes:
        fixed_s: Wall time of each reset with a fixed structure (the first, which compiles, left out).
        random_s: Wall time of each reset of the default env (random targets and distractors).
        rss_mb: Resident size after ``n`` random resets, for each checkpoint ``n`` of :data:`RSS_CHECKPOINTS`.
        compiles, reuses: Models compiled and scenes built on a kept model over the random resets.
    """

    fixed_s: list[float] = field(default_factory=list)
    random_s: list[float] = field(default_factory=list)
    rss_mb: dict[int, float] = field(default_factory=dict)
    compiles: int = 0
    reuses: int = 0

    @property
    def rss_growth_mb(self) -> float:
        """Resident size growth from the first checkpoint (5 resets) to the last, MB."""
        if len(self.rss_mb) < 2:
            return float("nan")
        ks = sorted(self.rss_mb)
        return self.rss_mb[ks[-1]] - self.rss_mb[ks[0]]

    def rows(self) -> list[tuple[str, str]]:
        """(measure, value) rows of the reset table."""
        out = []
        for label, t in (("fixed structure", self.fixed_s), ("random targets", self.random_s)):
            if t:
                ms = 1e3 * np.asarray(t)
                out.append((f"reset ms, {label} ({len(ms)}): median / p95",
                            f"{np.median(ms):.1f} / {np.percentile(ms, 95):.1f}"))
        if self.compiles + self.reuses:
            out.append(("random resets on a kept model / compiled", f"{self.reuses} / {self.compiles}"))
        for n, mb in sorted(self.rss_mb.items()):
            out.append((f"RSS after {n} random resets, MB", f"{mb:.0f}"))
        if len(self.rss_mb) >= 2:
            ks = sorted(self.rss_mb)
            out.append((f"RSS growth {ks[0]} -> {ks[-1]} resets, MB (<= 100)", f"{self.rss_growth_mb:.0f}"))
        return out


def _actions(env, n_steps: int, seed: int) -> np.ndarray:
    """``n_steps`` random actions of ``env`` (seeded), the rotation part scaled down to 30 %."""
    actions = np.random.default_rng(seed).uniform(env.action_space.low, env.action_space.high,
                                                  (n_steps, env.action_space.shape[0])).astype(np.float32)
    actions[:, 3:6] *= 0.3
    return actions


def _time_steps(env, start, actions: np.ndarray) -> float:
    """Seconds ``env.step`` takes over ``actions`` from the state ``start`` (an ``MjData`` copy)."""
    mujoco.mj_copyData(env.data, env.model, start)
    env.sync_command()
    t0 = time.perf_counter()
    for a in actions:
        env.step(a)
    return time.perf_counter() - t0


def bench_resets(n_resets: int = 500, n_fixed: int = 50, width: int = 320, height: int = 240,
                 seed: int = 0) -> ResetBench:
    """Time :meth:`PandaGraspEnv.reset` and record the resident size (see the module docstring).

    Args:
        n_resets: Resets of the default env (random targets, two random distractors, object set ``builtin``).
        n_fixed: Resets with a fixed structure (target ``can_0``, no distractors), after one untimed reset.
        width, height: Wrist camera size, pixels.
        seed: Seed of the first reset; each reset uses the next.
    """
    from simtest.envs.grasp_env import PandaGraspEnv
    from simtest.envs.model_cache import resident_mb
    from simtest.envs.options import load_objects
    from simtest.envs.scene import rest_rotation

    out = ResetBench()
    for obj in load_objects("builtin"):  # per-object caches (grasp sets, resting poses) filled once, untimed
        _ = obj.graspable
        rest_rotation(obj)
    env = PandaGraspEnv(width=width, height=height)
    for i in range(int(n_resets)):
        t0 = time.perf_counter()
        env.reset(seed=seed + i)
        out.random_s.append(time.perf_counter() - t0)
        if i + 1 in RSS_CHECKPOINTS:
            out.rss_mb[i + 1] = resident_mb() or float("nan")
    models = env.task.models
    out.compiles, out.reuses = (models.compiles, models.reuses) if models is not None else (0, 0)
    fixed = {"target": "can_0", "n_distractors": 0}
    env.reset(seed=seed, options=fixed)  # may compile: not timed
    for i in range(int(n_fixed)):
        t0 = time.perf_counter()
        env.reset(seed=seed + i, options=fixed)
        out.fixed_s.append(time.perf_counter() - t0)
    env.close()
    return out


def bench_pool_steps(width: int = 320, height: int = 240, n_steps: int = 40, seed: int = 0,
                     rounds: int = 7) -> dict[str, tuple[float, float]]:
    """Env steps/s of one episode on the pool model and on a model of its own objects (see the module
    docstring): ``{"without images": (pool, own), "with images": (pool, own)}``, control steps/s."""
    from simtest.envs.grasp_env import PandaGraspEnv

    opts = {"target": "can_0", "n_distractors": 2}
    envs = []
    for pool in (True, False):
        env = PandaGraspEnv(width=width, height=height, model_pool=pool)
        env.reset(seed=seed, options=opts)
        envs.append((env, copy.copy(env.data)))
    actions = _actions(envs[0][0], n_steps, seed)

    def run(env, start, images: bool) -> float:
        env.observe_every_step = images
        return _time_steps(env, start, actions)

    out = {}
    for images in (False, True):
        best = [float("inf"), float("inf")]
        for k in range(int(rounds)):
            for i in ((0, 1) if k % 2 else (1, 0)):
                best[i] = min(best[i], run(*envs[i], images))
        out["with images" if images else "without images"] = (n_steps / best[0], n_steps / best[1])
    for env, _ in envs:
        env.close()
    return out


@dataclass
class GraspBench:
    """Results of :func:`bench_grasp` (times in seconds)."""

    width: int
    height: int
    env_physics_steps_per_s: float
    raw_physics_steps_per_s: float
    env_steps_per_s_with_images: float
    work_outside_physics: float = float("nan")
    episode_wall_s: list[float] = field(default_factory=list)
    episode_success: list[bool] = field(default_factory=list)
    episode_targets: list[str] = field(default_factory=list)
    resets: ResetBench | None = None
    pool_vs_structure: dict[str, tuple[float, float]] = field(default_factory=dict)

    @property
    def step_overhead(self) -> float:
        """Extra wall time per physics step of the env over raw ``mj_step`` (0.1 = 10 %)."""
        return self.raw_physics_steps_per_s / self.env_physics_steps_per_s - 1.0

    def table(self) -> str:
        lines = [
            f"grasp env benchmark ({self.width}x{self.height} wrist camera)",
            f"{'measure':50s} {'value':>12s}",
            f"{'raw mj_step, physics steps/s':50s} {self.raw_physics_steps_per_s:12.0f}",
            f"{'env.step without images, physics steps/s':50s} {self.env_physics_steps_per_s:12.0f}",
            f"{'step overhead vs raw (target <= 20%)':50s} {100 * self.step_overhead:11.1f}%",
            f"{'  of which env work outside mj_step':50s} {100 * self.work_outside_physics:11.1f}%",
            f"{'env.step with RGB-D images, steps/s (20 Hz)':50s} {self.env_steps_per_s_with_images:12.1f}",
        ]
        if self.episode_wall_s:
            w = np.asarray(self.episode_wall_s)
            lines += [
                f"{'oracle episodes':50s} {len(w):12d}",
                f"{'episode wall s, mean (target <= 10 s)':50s} {w.mean():12.2f}",
                f"{'episode wall s, max':50s} {w.max():12.2f}",
                f"{'episode successes':50s} {sum(self.episode_success):9d}/{len(w):2d}",
            ]
        for what, (pool, own) in self.pool_vs_structure.items():
            lines += [f"{'env.step ' + what + ', pool / own model, steps/s':50s} {pool:5.0f} / {own:5.0f}",
                      f"{'  ratio pool / own model (target >= 0.95)':50s} {pool / own:12.3f}"]
        if self.resets is not None:
            lines += [f"{name:50s} {value:>12s}" for name, value in self.resets.rows()]
        return "\n".join(lines)


def bench_grasp(episodes: int = 3, width: int = 320, height: int = 240, n_steps: int = 100,
                seed: int = 0, rounds: int = 9, resets: int = 500) -> GraspBench:
    """Measure the grasp env (see the module docstring).

    Args:
        episodes: Oracle episodes timed (targets: a can, a box, a mug, a banana, ... in turn).
        width, height: Wrist camera size, pixels.
        n_steps: Env steps (20 Hz) per timing round.
        seed: Env seed.
        rounds: Timing rounds of the env and of raw ``mj_step``, interleaved; the fastest of each is kept
            (on a shared machine the slow rounds measure the neighbours, not the code).
        resets: Random-target resets of :func:`bench_resets` (0 skips the reset benchmark); run first.
    """
    from simtest.envs.episode import run_episode
    from simtest.envs.grasp_env import PandaGraspEnv
    from simtest.estimators.oracle import OracleEstimator

    reset_bench = bench_resets(resets, min(50, max(int(resets), 1)), width, height, seed) if resets > 0 else None
    env = PandaGraspEnv(width=width, height=height, observe_every_step=False)
    env.reset(seed=seed, options={"target": "can_0", "n_distractors": 2})
    actions = _actions(env, n_steps, seed)
    n_sub = int(round(0.05 / env.model.opt.timestep))
    start = copy.copy(env.data)

    inside = [0.0]

    def run_env() -> float:
        return _time_steps(env, start, actions)

    def run_env_split() -> tuple[float, float]:
        """Total time and time inside ``mj_step`` of the same loop (``mj_step`` wrapped by a timer)."""
        real = mujoco.mj_step

        def timed(m, d, n=1):
            t = time.perf_counter()
            real(m, d, n)
            inside[0] += time.perf_counter() - t

        inside[0] = 0.0
        mujoco.mj_step = timed
        try:
            total = run_env()
        finally:
            mujoco.mj_step = real
        return total, inside[0]

    ctrls = []
    mujoco.mj_copyData(env.data, env.model, start)
    env.sync_command()
    for a in actions:  # the controls the env produced, replayed for the raw run
        env.step(a)
        ctrls.append(env.data.ctrl.copy())

    def run_raw() -> float:
        m, d = env.model, copy.copy(start)
        t0 = time.perf_counter()
        for c in ctrls:
            d.ctrl[:] = c
            mujoco.mj_step(m, d, n_sub)
        return time.perf_counter() - t0

    t_env, t_raw = [], []
    for k in range(int(rounds)):  # interleaved, alternating order; the fastest of each is kept
        if k % 2:
            t_env.append(run_env())
            t_raw.append(run_raw())
        else:
            t_raw.append(run_raw())
            t_env.append(run_env())
    phys = n_steps * n_sub
    env_rate, raw_rate = phys / min(t_env), phys / min(t_raw)
    splits = [run_env_split() for _ in range(3)]
    outside = min((tot - ins) / ins for tot, ins in splits)

    env.observe_every_step = True
    k = min(n_steps, 40)
    img_rate = k / _time_steps(env, start, actions[:k])
    env.close()

    out = GraspBench(width, height, env_rate, raw_rate, img_rate, outside, resets=reset_bench,
                     pool_vs_structure=bench_pool_steps(width, height, seed=seed))
    targets = ["can_0", "box_0", "mug_0", "banana_0", "bottle_1", "drill_0", "cup_0", "bowl_0", "marker_0"]
    ep_env = PandaGraspEnv(width=width, height=height)
    oracle = OracleEstimator()
    ep_env.reset(seed=seed, options={"target": targets[0]})  # load the object set outside the timing
    for i in range(int(episodes)):
        name = targets[i % len(targets)]
        res = run_episode(ep_env, oracle, seed=seed + i, options={"target": name, "n_distractors": 2})
        out.episode_wall_s.append(res.wall_s)
        out.episode_success.append(res.success)
        out.episode_targets.append(name)
    ep_env.close()
    return out
