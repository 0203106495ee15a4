"""A lean differential-IK step for the 20 Hz end-effector control of the grasp env.

It has the contract of :func:`simtest.panda.ik_step` (move the TCP from its pose at the commanded joints toward
a target by at most a given distance and angle; return joint targets within the limits) but does one damped
least-squares step (and one correcting step) with a null-space pull toward the ready posture, using MuJoCo's own rotation functions
instead of SciPy. That keeps the env's work per control step a small fraction of its 25 physics steps (see
:mod:`simtest.benchmarks.grasp`); :func:`simtest.panda.ik_step` (three iterations) stays available through
``PandaGraspEnv(ik="panda")``.
"""

from __future__ import annotations

import numpy as np

import simtest  # noqa: F401
import mujoco

from simtest.panda import HOME_QPOS, PandaIds

__all__ = ["DiffIK", "rotvec_to_matrix"]


def rotvec_to_matrix(rv: np.ndarray) -> np.ndarray:
    """Rotation matrix of a rotation vector (axis * angle, rad), Rodrigues' formula."""
    rv = np.asarray(rv, dtype=np.float64)
    angle = float(np.sqrt(rv @ rv))
    if angle < 1e-12:
        return np.eye(3)
    k = rv / angle
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(angle) * K + (1.0 - np.cos(angle)) * (K @ K)


def _as_slice(idx: np.ndarray) -> slice | np.ndarray:
    """A slice for consecutive indices (cheaper to index with), the index array otherwise."""
    idx = np.asarray(idx)
    if len(idx) and np.all(np.diff(idx) == 1):
        return slice(int(idx[0]), int(idx[-1]) + 1)
    return idx


class DiffIK:
    """One-step differential IK on the Panda's TCP site.

    Args:
        model: The compiled model with the Panda.
        ids: The Panda's ids.
        damping: DLS damping (m, rad scale).
        posture_gain: Null-space pull toward ``posture`` per step (fraction of the offset).
        posture: Preferred configuration (7,) rad; default :data:`simtest.panda.HOME_QPOS`.
        refine: Take a second, correcting DLS step in :meth:`step_delta`.
    """

    def __init__(self, model: mujoco.MjModel, ids: PandaIds, damping: float = 0.03, posture_gain: float = 0.02,
                 posture: np.ndarray | None = None, refine: bool = True) -> None:
        self.model = model
        self.ids = ids
        self.data = mujoco.MjData(model)
        self.damping2 = float(damping) ** 2
        self.posture_gain = float(posture_gain)
        self.refine = bool(refine)
        self.posture = HOME_QPOS.copy() if posture is None else np.asarray(posture, dtype=np.float64)
        self.lo = ids.arm_limits[:, 0].copy()
        self.hi = ids.arm_limits[:, 1].copy()
        self._jacp = np.zeros((3, model.nv))
        self._jacr = np.zeros((3, model.nv))
        self._q_err = np.zeros(4)
        self._q_a = np.zeros(4)
        self._q_b = np.zeros(4)
        self._rv = np.zeros(3)
        self._q_target = np.zeros(4)
        self._e = np.zeros(6)
        self._J = np.zeros((6, 7))
        self._qsl = _as_slice(ids.arm_qpos)
        self._dsl = _as_slice(ids.arm_dof)

    def fk(self, q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """TCP position (3,) m and rotation (3, 3) at arm configuration ``q`` (rad)."""
        d = self.data
        d.qpos[self.ids.arm_qpos] = q
        mujoco.mj_kinematics(self.model, d)
        s = self.ids.tcp_site
        return d.site_xpos[s].copy(), d.site_xmat[s].reshape(3, 3).copy()

    def _rot_error(self, R_target: np.ndarray, R: np.ndarray) -> np.ndarray:
        """World-frame rotation vector taking ``R`` to ``R_target`` (rad)."""
        mujoco.mju_mat2Quat(self._q_a, np.ascontiguousarray(R_target).reshape(9))
        mujoco.mju_mat2Quat(self._q_b, np.ascontiguousarray(R).reshape(9))
        mujoco.mju_negQuat(self._q_b, self._q_b)
        mujoco.mju_mulQuat(self._q_err, self._q_a, self._q_b)
        mujoco.mju_quat2Vel(self._rv, self._q_err, 1.0)
        return self._rv.copy()

    def step_delta(self, q: np.ndarray, dp: np.ndarray, rotvec: np.ndarray, lo: np.ndarray,
                   hi: np.ndarray) -> np.ndarray:
        """Joint targets (7,) rad that move the TCP at ``q`` by ``dp`` (m, world frame; the target is clipped
        to the box ``[lo, hi]``) and rotate it by ``rotvec`` (rad, world frame, about the TCP).

        A damped least-squares step on the TCP Jacobian at ``q`` with a null-space pull toward the ready
        posture, and (``refine``) a second step with the same Jacobian correcting the first's linearisation
        and damping error (five 2 cm steps then land within about 0.2 mm); clamped to the joint limits.
        """
        m, d = self.model, self.data
        d.qpos[self._qsl] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        s = self.ids.tcp_site
        pos = d.site_xpos[s]
        target = np.minimum(np.maximum(pos + dp, lo), hi)
        e = self._e
        e[:3] = target - pos
        e[3:] = rotvec
        mujoco.mj_jacSite(m, d, self._jacp, self._jacr, s)
        J = self._J
        J[:3] = self._jacp[:, self._dsl]
        J[3:] = self._jacr[:, self._dsl]
        A = J @ J.T
        A.flat[::7] += self.damping2
        A_inv = np.linalg.inv(A)
        null = self.posture_gain * (self.posture - q)
        q1 = q + J.T @ (A_inv @ (e - J @ null)) + null
        if self.refine:
            # A second (quasi-Newton) step with the same Jacobian removes most of the first step's
            # linearisation and damping error; only the kinematics are recomputed.
            qt = self._q_target
            mujoco.mju_mat2Quat(self._q_b, d.site_xmat[s])
            angle = float(np.sqrt(rotvec @ rotvec))
            if angle > 1e-12:
                mujoco.mju_axisAngle2Quat(self._q_a, rotvec / angle, angle)
                mujoco.mju_mulQuat(qt, self._q_a, self._q_b)
            else:
                qt[:] = self._q_b
            d.qpos[self._qsl] = q1
            mujoco.mj_kinematics(m, d)
            e[:3] = target - d.site_xpos[s]
            mujoco.mju_mat2Quat(self._q_b, d.site_xmat[s])
            mujoco.mju_negQuat(self._q_b, self._q_b)
            mujoco.mju_mulQuat(self._q_err, qt, self._q_b)
            mujoco.mju_quat2Vel(self._rv, self._q_err, 1.0)
            e[3:] = self._rv
            q1 = q1 + J.T @ (A_inv @ e)
        return np.minimum(np.maximum(q1, self.lo), self.hi)

    def _dls(self, q: np.ndarray, e: np.ndarray) -> np.ndarray:
        m, d, ids = self.model, self.data, self.ids
        mujoco.mj_jacSite(m, d, self._jacp, self._jacr, ids.tcp_site)
        J = np.empty((6, 7))
        J[:3] = self._jacp[:, ids.arm_dof]
        J[3:] = self._jacr[:, ids.arm_dof]
        A = J @ J.T
        A[np.diag_indices(6)] += self.damping2
        B = np.empty((6, 8))
        B[:, 0] = e
        B[:, 1:] = J
        X = np.linalg.solve(A, B)  # (J J^T + l^2 I)^-1 [e, J]
        null = self.posture_gain * (self.posture - q)
        dq = J.T @ (X[:, 0] - X[:, 1:] @ null) + null
        return np.minimum(np.maximum(q + dq, self.lo), self.hi)

    def step(self, q: np.ndarray, target_pos: np.ndarray, target_R: np.ndarray, max_dist: float,
             max_angle: float) -> np.ndarray:
        """Joint targets (7,) rad moving the TCP from its pose at ``q`` toward the target.

        The step is limited to ``max_dist`` metres and ``max_angle`` radians (scaled together, so the TCP
        moves along the straight line and the slerp toward the target) and clamped to the joint limits.
        """
        m, d, ids = self.model, self.data, self.ids
        q = np.asarray(q, dtype=np.float64)
        d.qpos[ids.arm_qpos] = q
        mujoco.mj_kinematics(m, d)
        mujoco.mj_comPos(m, d)
        s = ids.tcp_site
        e_p = np.asarray(target_pos, dtype=np.float64) - d.site_xpos[s]
        e_r = self._rot_error(target_R, d.site_xmat[s].reshape(3, 3))
        dist, ang = float(np.sqrt(e_p @ e_p)), float(np.sqrt(e_r @ e_r))
        scale = 1.0
        if dist > max_dist:
            scale = max_dist / dist
        if ang > max_angle:
            scale = min(scale, max_angle / ang)
        return self._dls(q, np.concatenate([e_p, e_r]) * scale)
