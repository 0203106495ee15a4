"""Physics settling: drop the objects, step until they rest, and take off the ones that fell off the table."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

import simtest  # noqa: F401
import mujoco

from simtest.generators.builder import SimScene
from simtest.generators.config import SceneConfig

__all__ = ["SettleResult", "settle", "FAR_AWAY"]

#: Rotational damping of free bodies while settling, per kg m^2 of their largest principal inertia (1/s).
ROCKING_DAMPING = 5.0
#: Where removed objects are parked (metres): far outside every camera's far plane, above the floor (whose plane
#: collides as a half-space: a body parked below it would be in contact, 500 m deep).
FAR_AWAY = np.array([500.0, 500.0, 500.0])


@dataclass(frozen=True)
class SettleResult:
    """Outcome of settling.

    Attributes:
        sim_time: Simulated seconds until rest (or the cap).
        at_rest: Whether every object dropped below the velocity threshold before the cap.
        removed: Instance indices taken off because they fell off the table (or out of the bin).
        max_speed: Fastest point of any free body still on the table at the end (m/s), see :func:`body_speed`.
    """

    sim_time: float
    at_rest: bool
    removed: tuple[int, ...]
    max_speed: float


def _free_bodies(model: mujoco.MjModel) -> list[tuple[int, int, int]]:
    """(body id, qpos address, dof address) of every body with a free joint."""
    out = []
    for b in range(model.nbody):
        j = model.body_jntadr[b]
        if model.body_jntnum[b] == 1 and model.jnt_type[j] == mujoco.mjtJoint.mjJNT_FREE:
            out.append((b, int(model.jnt_qposadr[j]), int(model.jnt_dofadr[j])))
    return out


def body_radius(model: mujoco.MjModel, body: int) -> float:
    """Radius (metres) of a sphere about the body origin that holds all its geoms."""
    adr, n = model.body_geomadr[body], model.body_geomnum[body]
    if n == 0:
        return 0.0
    return float(max(np.linalg.norm(model.geom_pos[g]) + model.geom_rbound[g] for g in range(adr, adr + n)))


def body_speed(model: mujoco.MjModel, data: mujoco.MjData, body: int, dof: int, radius: float) -> float:
    """Fastest point speed bound of a free body (m/s): |v| + |omega| * radius."""
    v = data.qvel[dof:dof + 6]
    return float(np.linalg.norm(v[:3]) + np.linalg.norm(v[3:]) * radius)


def settle(scene: SimScene, cfg: SceneConfig, quiet_time: float = 0.1) -> SettleResult:
    """Step the physics until all free bodies are at rest for ``quiet_time`` s, or ``cfg.settle_max_time``.

    At rest means no point of any body moves faster than ``cfg.settle_velocity`` (m/s).

    A body that drops below the table top (it fell off) is parked at :data:`FAR_AWAY` as soon as it is seen,
    so it neither keeps the scene "moving" nor appears in images; fallen object instances, and those that end
    outside the table's footprint (the room's floor without a table), are marked inactive in ``scene.active`` and reported in ``removed``.
    """
    m, d = scene.model, scene.data
    bodies = _free_bodies(m)
    dt = m.opt.timestep
    steps_max = int(np.ceil(cfg.settle_max_time / dt))
    quiet_steps = max(1, int(round(quiet_time / dt)))
    check_every = 10
    quiet = 0
    speed = np.inf
    step = 0
    floor_z = cfg.table_height - 0.02
    parked: set[int] = set()
    # Light rotational damping (time constant ~0.2 s) ends the slow rocking of curved objects (a banana on
    # its side) without changing where they come to rest; translation stays undamped so drops are free fall.
    radius = {b: body_radius(m, b) for b, _, _ in bodies}
    for b, _, vadr in bodies:
        m.dof_damping[vadr + 3:vadr + 6] = ROCKING_DAMPING * float(np.max(m.body_inertia[b]))
    while step < steps_max:
        mujoco.mj_step(m, d, nstep=check_every)  # the same steps as one call each, in one release of the GIL
        step += check_every
        speed = 0.0
        for b, qadr, vadr in bodies:
            if b in parked:
                continue
            if d.xpos[b][2] < floor_z:
                _park_body(m, d, b, qadr, vadr, len(parked))
                parked.add(b)
                continue
            speed = max(speed, body_speed(m, d, b, vadr, radius[b]))
        quiet = quiet + check_every if speed < cfg.settle_velocity else 0
        if quiet >= quiet_steps:
            break
    removed = []
    hx, hy = cfg.table_size[0] / 2, cfg.table_size[1] / 2
    if cfg.table_height <= 0.0:  # no table: objects rest anywhere on the room's floor
        hx = hy = cfg.room_half_size
    for i, b in enumerate(scene.instance_bodies):
        x, y, z = d.xpos[b]
        if b in parked or z < cfg.table_height - 0.005 or abs(x) > hx or abs(y) > hy:
            removed.append(i)
    for i in removed:
        park(scene, i)
    mujoco.mj_forward(m, d)
    return SettleResult(float(step * dt), bool(quiet >= quiet_steps), tuple(removed), float(speed))


def _park_body(m: mujoco.MjModel, d: mujoco.MjData, body: int, qadr: int, vadr: int, k: int) -> None:
    m.body_gravcomp[body] = 1.0  # parked bodies float instead of falling forever
    d.qpos[qadr:qadr + 3] = FAR_AWAY + [0.0, 10.0 * (k + 1), 0.0]
    d.qpos[qadr + 3:qadr + 7] = [1.0, 0.0, 0.0, 0.0]
    d.qvel[vadr:vadr + 6] = 0.0


def park(scene: SimScene, instance: int) -> None:
    """Move an instance far away, stop it, and mark it inactive (it is no longer annotated or drawn)."""
    q = scene.instance_qpos[instance]
    scene.data.qpos[q:q + 3] = FAR_AWAY + [10.0 * instance, 0.0, 0.0]
    scene.data.qpos[q + 3:q + 7] = [1.0, 0.0, 0.0, 0.0]
    v = scene.instance_dofs[instance]
    scene.data.qvel[v:v + 6] = 0.0
    scene.model.body_gravcomp[scene.instance_bodies[instance]] = 1.0
    scene.active[instance] = False
