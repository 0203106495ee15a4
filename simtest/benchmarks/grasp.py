"""``simtest bench grasp``: grasp-env speed as a ratio against raw ``mj_step`` of the same model, same run.

* **Step overhead**: wall time per physics step of :meth:`PandaGraspEnv.step` without image observations
  (``observe_every_step=False``: differential IK, servo commands, 25 physics steps, kinematics, state
  observation and ground-truth ``info``) against ``mujoco.mj_step`` of the same model from the same state with
  the same controls. Target: at most 20 % overhead.
  The wall-clock ratio includes whatever else the machine runs; the env's own work (IK, observation,
  ``info``), timed outside ``mj_step`` in the same loop, is reported too.
* **Steps with images**: env steps/s when every step renders the wrist RGB-D observation (for reference).
* **Episode wall time**: :func:`simtest.envs.episode.run_episode` with the zero-noise oracle (reset, scene
  build and settling included). Target: at most 10 s per episode.
"""

from __future__ import annotations

import copy
import time
from dataclasses import dataclass, field

import numpy as np

import simtest  # noqa: F401
import mujoco

__all__ = ["GraspBench", "bench_grasp"]


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

    @property
    def step_overhead(self) -> float:
        """Extra wall time per physics step of the env over raw ``mj_step`` (0.1 = 10 %)."""
        return self.raw_physics_steps_per_s / self.env_physics_steps_per_s - 1.0

    def table(self) -> str:
        lines = [
            f"grasp env benchmark ({self.width}x{self.height} wrist camera)",
            f"{'measure':44s} {'value':>12s}",
            f"{'raw mj_step, physics steps/s':44s} {self.raw_physics_steps_per_s:12.0f}",
            f"{'env.step without images, physics steps/s':44s} {self.env_physics_steps_per_s:12.0f}",
            f"{'step overhead vs raw (target <= 20%)':44s} {100 * self.step_overhead:11.1f}%",
            f"{'  of which env work outside mj_step':44s} {100 * self.work_outside_physics:11.1f}%",
            f"{'env.step with RGB-D images, steps/s (20 Hz)':44s} {self.env_steps_per_s_with_images:12.1f}",
        ]
        if self.episode_wall_s:
            w = np.asarray(self.episode_wall_s)
            lines += [
                f"{'oracle episodes':44s} {len(w):12d}",
                f"{'episode wall s, mean (target <= 10 s)':44s} {w.mean():12.2f}",
                f"{'episode wall s, max':44s} {w.max():12.2f}",
                f"{'episode successes':44s} {sum(self.episode_success):9d}/{len(w):2d}",
            ]
        return "\n".join(lines)


def bench_grasp(episodes: int = 3, width: int = 320, height: int = 240, n_steps: int = 100,
                seed: int = 0, rounds: int = 9) -> GraspBench:
    """Measure the grasp env (see the module docstring).

    Args:
        episodes: Oracle episodes timed (targets: a can, a box, a mug, a banana, ... in turn).
        width, height: Wrist camera size, pixels.
        n_steps: Env steps (20 Hz) per timing round.
        seed: Env seed.
        rounds: Timing rounds of the env and of raw ``mj_step``, interleaved; the fastest of each is kept
            (on a shared machine the slow rounds measure the neighbours, not the code).
    """
    from simtest.envs.episode import run_episode
    from simtest.envs.grasp_env import PandaGraspEnv
    from simtest.estimators.oracle import OracleEstimator

    env = PandaGraspEnv(width=width, height=height, observe_every_step=False)
    env.reset(seed=seed, options={"target": "can_0", "n_distractors": 2})
    rng = np.random.default_rng(seed)
    actions = rng.uniform(env.action_space.low, env.action_space.high, (n_steps, 7)).astype(np.float32)
    actions[:, 3:6] *= 0.3
    n_sub = int(round(0.05 / env.model.opt.timestep))
    start = copy.copy(env.data)

    inside = [0.0]

    def run_env() -> float:
        mujoco.mj_copyData(env.data, env.model, start)
        env.sync_command()
        t0 = time.perf_counter()
        for a in actions:
            env.step(a)
        return time.perf_counter() - t0

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
    mujoco.mj_copyData(env.data, env.model, start)
    env.sync_command()
    k = min(n_steps, 40)
    t0 = time.perf_counter()
    for a in actions[:k]:
        env.step(a)
    img_rate = k / (time.perf_counter() - t0)
    env.close()

    out = GraspBench(width, height, env_rate, raw_rate, img_rate, outside)
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
