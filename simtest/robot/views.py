"""Wrist-camera viewpoints: arm configurations whose wrist camera looks at a point from random directions."""

from __future__ import annotations

import numpy as np

import simtest  # noqa: F401  (selects the GL backend before mujoco is imported)
import mujoco

from simtest.camera import look_at_pose
from simtest.errors import ConfigError
from simtest.robot.asset import HOME_QPOS
from simtest.robot.ids import PandaIds
from simtest.robot.ik import solve_ik
from simtest.robot.state import in_collision, scratch_data

__all__ = ["sample_wrist_views"]


def sample_wrist_views(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    ids: PandaIds,
    look_at_point: np.ndarray,
    rng: np.random.Generator,
    n: int,
    distance_range: tuple[float, float] = (0.25, 0.6),
    *,
    elevation_range: tuple[float, float] = (np.deg2rad(25.0), np.deg2rad(85.0)),
    azimuth_halfwidth: float = 0.6 * np.pi,
    roll_range: tuple[float, float] = (-np.pi / 2, np.pi / 2),
    check_collisions: bool = True,
    max_attempts: int | None = None,
    allow_fewer: bool = False,
) -> list[np.ndarray]:
    """Arm configurations whose wrist camera looks at ``look_at_point`` from random viewpoints.

    Each viewpoint is drawn with ``rng``: distance uniform in ``distance_range`` (m, camera centre to the
    point), elevation above the horizontal uniform in ``elevation_range`` (rad), azimuth uniform within
    ``azimuth_halfwidth`` (rad) of the direction from the point toward the robot base, and an in-plane
    roll uniform in ``roll_range`` (rad; 0 = image "up" toward world +z). IK is solved for the camera
    frame itself (not the TCP), so the point lands on the principal point to within 0.5 mm / 0.3 deg.
    Viewpoints without an IK solution or, with ``check_collisions``, where the robot touches anything at
    the current state of the other bodies, are rejected.

    Args:
        model, data, ids: Model, state (read only) and the Panda's ids; needs the wrist camera.
        look_at_point: World point (3,), m.
        rng: Random generator.
        n: Number of configurations wanted.
        distance_range: (min, max) camera distance, m.
        max_attempts: Viewpoints tried before giving up; default ``30 * n``.
        allow_fewer: Return what was found instead of raising when fewer than ``n`` were found.

    Returns:
        ``n`` arm configurations (7,), rad (fewer only with ``allow_fewer``).

    Raises:
        ConfigError: On bad ranges, or when fewer than ``n`` views were found (unless ``allow_fewer``).
    """
    if ids.camera < 0:
        raise ConfigError("sample_wrist_views needs a wrist camera (attach_panda(..., wrist_camera=...))")
    lo_d, hi_d = map(float, distance_range)
    if not 0 < lo_d <= hi_d:
        raise ConfigError(f"distance_range must satisfy 0 < min <= max (m), got {distance_range!r}")
    lo_e, hi_e = map(float, elevation_range)
    if not -np.pi / 2 <= lo_e <= hi_e <= np.pi / 2:
        raise ConfigError(f"elevation_range must lie in [-pi/2, pi/2] rad with min <= max, got "
                          f"{elevation_range!r}")
    if n < 0:
        raise ConfigError(f"n must be >= 0, got {n!r}")
    point = np.asarray(look_at_point, dtype=np.float64).reshape(3)
    scratch = scratch_data(model, data)
    mujoco.mj_kinematics(model, scratch)
    to_base = scratch.xpos[ids.base_body][:2] - point[:2]
    az0 = float(np.arctan2(to_base[1], to_base[0])) if np.linalg.norm(to_base) > 1e-6 else 0.0
    attempts = 30 * n if max_attempts is None else int(max_attempts)
    views: list[np.ndarray] = []
    q_start = HOME_QPOS
    for _ in range(attempts):
        if len(views) >= n:
            break
        dist = rng.uniform(lo_d, hi_d)
        el = rng.uniform(lo_e, hi_e)
        az = az0 + rng.uniform(-azimuth_halfwidth, azimuth_halfwidth)
        roll = rng.uniform(*roll_range)
        eye = point + dist * np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
        T_world_cam = look_at_pose(eye, point, roll=roll)
        res = solve_ik(model, data, ids, T_world_cam, q_start, frame="camera", restarts=2, rng=rng)
        if not res.success:
            continue
        if check_collisions and in_collision(model, data, ids, res.q):
            continue
        views.append(res.q)
    if len(views) < n and not allow_fewer:
        raise ConfigError(
            f"found {len(views)} of {n} reachable wrist views of point {np.round(point, 3).tolist()} m in "
            f"{attempts} attempts (distance {distance_range} m, elevation {np.round(elevation_range, 3)} rad)"
            "; move the point closer to the robot, widen the ranges or pass allow_fewer=True")
    return views

