"""Physics settling: drop the objects, step until they rest, and take off the ones that fell off the table.

:func:`settle` changes the model only while it runs (rotational damping of free bodies, MuJoCo's sleeping) and
restores both; what it leaves is the state at rest and the fallen instances parked (floating far away).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

import simtest  # noqa: F401
import mujoco

from simtest.errors import ConfigError
from simtest.generators.build_options import Room, SettleOptions
from simtest.generators.builder import SimScene

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


def settle(scene: SimScene, options: SettleOptions, quiet_time: float = 0.1) -> SettleResult:
    """Step the physics until all free bodies are at rest for ``quiet_time`` s, or ``options.max_time`` s.

    At rest means no point of any body moves faster than ``options.velocity`` (m/s).

    A body that drops below the table top (it fell off) is parked at :data:`FAR_AWAY` as soon as it is seen,
    so it neither keeps the scene "moving" nor appears in images; fallen object instances, and those that end
    outside the table's footprint (the room's floor without a table), are marked inactive in ``scene.active``
    and reported in ``removed``. The model's damping and sleep flag are as they were when it returns.

    Raises:
        ConfigError: If ``options`` is not a :class:`SettleOptions`.
    """
    options = _settle_options(options)
    room = options.room
    m, d = scene.model, scene.data
    bodies = _free_bodies(m)
    dt = m.opt.timestep
    steps_max = int(np.ceil(options.max_time / dt))
    quiet_steps = max(1, int(round(quiet_time / dt)))
    floor_z = room.table_height - 0.02
    parked: set[int] = set()
    # Light rotational damping (time constant ~0.2 s) ends the slow rocking of curved objects (a banana on
    # its side) without changing where they come to rest; translation stays undamped so drops are free fall.
    radius = np.array([body_radius(m, b) for b, _, _ in bodies])
    damping = m.dof_damping.copy()
    for b, _, vadr in bodies:
        m.dof_damping[vadr + 3:vadr + 6] = ROCKING_DAMPING * float(np.max(m.body_inertia[b]))
    # MuJoCo's sleeping: a group of bodies at rest (below opt.sleep_tolerance) stops being simulated until
    # something touches it, so the steps cost less as the pile comes to rest (about a quarter less CPU time per
    # scene; rest poses within a few millimetres of full simulation). Only while settling: restored after.
    flags = int(m.opt.enableflags)
    m.opt.enableflags = flags | int(mujoco.mjtEnableBit.mjENBL_SLEEP)
    try:
        step, quiet, speed = _step_until_rest(m, d, bodies, radius, parked, floor_z, options.velocity,
                                              steps_max, quiet_steps)
    finally:
        m.opt.enableflags = flags
        m.dof_damping[:] = damping
    removed = []
    hx, hy = room.table_size[0] / 2, room.table_size[1] / 2
    if room.table_height <= 0.0:  # no table: objects rest anywhere on the room's floor
        hx = hy = room.room_half_size
    for i, b in enumerate(scene.instance_bodies):
        x, y, z = d.xpos[b]
        if b in parked or z < room.table_height - 0.005 or abs(x) > hx or abs(y) > hy:
            removed.append(i)
    for i in removed:
        park(scene, i)
    mujoco.mj_forward(m, d)
    return SettleResult(float(step * dt), bool(quiet >= quiet_steps), tuple(removed), float(speed))


def _settle_options(options: SettleOptions) -> SettleOptions:
    """``options``, or those of a config's ``scene`` section handed in their place (with a DeprecationWarning).

    Raises:
        ConfigError: If ``options`` is neither.
    """
    if isinstance(options, SettleOptions):
        return options
    if not all(hasattr(options, k) for k in ("settle_max_time", "settle_velocity", "table_height", "table_size",
                                             "room_half_size")):
        raise ConfigError(f"settle needs SettleOptions (a run config's settle_options()); got "
                          f"{type(options).__name__}")
    import warnings

    warnings.warn("settle takes SettleOptions; pass cfg.settle_options() instead of cfg.scene", DeprecationWarning,
                  stacklevel=3)
    room = Room(table_size=options.table_size, table_height=options.table_height,
                container=getattr(options, "container", "table"), room_half_size=options.room_half_size,
                wall_height=getattr(options, "wall_height", 1.6))
    return SettleOptions(max_time=options.settle_max_time, velocity=options.settle_velocity, room=room)


def _step_until_rest(m: mujoco.MjModel, d: mujoco.MjData, bodies: list[tuple[int, int, int]], radius: np.ndarray,
                     parked: set[int], floor_z: float, velocity: float, steps_max: int, quiet_steps: int,
                     check_every: int = 10) -> tuple[int, int, float]:
    """Step in blocks of ``check_every`` until every free body not parked is below ``velocity`` (m/s, fastest
    point: :func:`body_speed`) for ``quiet_steps`` steps, or ``steps_max``; bodies below ``floor_z`` are parked
    as they are seen (added to ``parked``).

    Returns:
        ``(steps taken, quiet steps at the end, fastest point speed in the last check)``.
    """
    ids = np.array([b for b, _, _ in bodies], dtype=np.int64)
    dofs = np.array([v for _, _, v in bodies], dtype=np.int64)[:, None] + np.arange(6)
    live = np.ones(len(bodies), dtype=bool)
    step = quiet = 0
    speed = np.inf
    while step < steps_max:
        mujoco.mj_step(m, d, nstep=check_every)  # the same steps as one call each, in one release of the GIL
        step += check_every
        fallen = np.flatnonzero(live & (d.xpos[ids, 2] < floor_z))
        for k in fallen:
            b, qadr, vadr = bodies[k]
            _park_body(m, d, b, qadr, vadr, len(parked))
            parked.add(b)
            live[k] = False
        v = d.qvel[dofs[live]]
        speed = float(np.max(np.linalg.norm(v[:, :3], axis=1) + np.linalg.norm(v[:, 3:], axis=1) * radius[live],
                             initial=0.0))
        quiet = quiet + check_every if speed < velocity else 0
        if quiet >= quiet_steps:
            break
    return step, quiet, speed


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
