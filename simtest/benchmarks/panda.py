"""Speed of the Panda model without rendering: ``simtest bench panda`` (or ``python -m simtest.benchmarks.panda``).

Scene: the Panda, a table and a free 5 cm box. Measures ``mj_step`` throughput with the arm holding its home
posture and while sweeping its joints, and the wall and simulated time of one scripted top-down
:func:`simtest.robot.grasp_and_lift` of the box.
"""

from __future__ import annotations

import time

import numpy as np

import simtest  # noqa: F401  (selects the GL backend before mujoco is imported)
import mujoco

from simtest.errors import ConfigError
from simtest.geometry import Pose
from simtest.robot import HOME_QPOS, PandaIds, attach_panda, grasp_and_lift, reset_arm

__all__ = ["benchmark", "table"]


def _benchmark_scene() -> tuple[mujoco.MjModel, mujoco.MjData, PandaIds]:
    """The Panda at its home posture, a table (top at z = 0) and a free 5 cm, 0.1 kg box on it."""
    spec = mujoco.MjSpec()
    spec.worldbody.add_geom(name="table", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.4, 0.6, 0.02],
                            pos=[0.55, 0.0, -0.02])
    body = spec.worldbody.add_body(name="box", pos=[0.5, 0.0, 0.025])
    body.add_freejoint()
    body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.025] * 3, mass=0.1)
    handles = attach_panda(spec)
    model = spec.compile()
    data = mujoco.MjData(model)
    ids = handles.bind(model)
    reset_arm(model, data, ids)
    return model, data, ids


def benchmark(n_steps: int = 5000) -> dict[str, float]:
    """Speed of the Panda + table + 5 cm box model, without rendering.

    Returns:
        ``steps_per_s`` (``mj_step`` calls per wall second with the arm holding its home posture),
        ``realtime_factor`` (simulated / wall time of that), ``steps_per_s_moving`` (the arm sweeping
        its joints), ``grasp_wall_s`` and ``grasp_sim_s`` (one scripted
        top-down :func:`grasp_and_lift` of the box) and ``grasp_success`` (1.0 or 0.0).
    """
    if n_steps < 25:
        raise ConfigError(f"n_steps must be >= 25 (one sweep chunk), got {n_steps!r}")
    model, data, ids = _benchmark_scene()
    mujoco.mj_step(model, data, 100)
    t0 = time.perf_counter()
    mujoco.mj_step(model, data, n_steps)
    wall = time.perf_counter() - t0
    # Arm in motion (joint targets swept every 25 steps), box resting on the table.
    model, data, ids = _benchmark_scene()
    chunk = 25
    t0 = time.perf_counter()
    for k in range(n_steps // chunk):
        data.ctrl[ids.arm_actuators] = HOME_QPOS + 0.3 * np.sin(0.05 * k + np.arange(7))
        mujoco.mj_step(model, data, chunk)
    wall_moving = time.perf_counter() - t0
    model, data, ids = _benchmark_scene()
    mujoco.mj_step(model, data, 100)
    box = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "box")
    grasp = Pose(np.diag([1.0, -1.0, -1.0]), data.xpos[box].copy())
    t0 = time.perf_counter()
    result = grasp_and_lift(model, data, ids, grasp, box)
    grasp_wall = time.perf_counter() - t0
    return {
        "steps_per_s": n_steps / wall,
        "realtime_factor": n_steps * model.opt.timestep / wall,
        "steps_per_s_moving": (n_steps // chunk) * chunk / wall_moving,
        "grasp_wall_s": grasp_wall,
        "grasp_sim_s": result.sim_time,
        "grasp_success": float(result.success),
    }


def table(results: dict[str, float]) -> str:
    """One ``name: value`` line per figure of :func:`benchmark`."""
    return "\n".join(f"{key}: {value:.4g}" for key, value in results.items())


if __name__ == "__main__":
    print(table(benchmark()))
