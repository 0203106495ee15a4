"""Scripted arm motion under watch: the collision monitor of an episode's phases, joint-space moves and the way
to the pre-grasp pose (forces in newtons, lengths in metres, times in seconds).

:class:`PhaseMonitor` runs every control period: it feeds the optional recorder and, in the phases ``free``,
``descent`` and ``approach``, raises :class:`Collision` when the robot pushes against the table or another
object harder than :data:`COLLISION_FORCE` (or touches the target before the approach), and
:class:`TableTouch` when the fingertips meet the table during the approach (a guarded move).
"""

from __future__ import annotations

import numpy as np

import simtest  # noqa: F401
import mujoco

from simtest.envs.options import CONTROL_DT
from simtest.envs.planner import GraspPlan
from simtest.envs.recording import EpisodeRecorder
from simtest.envs.task import GraspTask, as_task
from simtest.robot import min_jerk, move_to, set_gripper, tcp_pose

__all__ = ["COLLISION_FORCE", "GUARD_FORCE", "Collision", "TableTouch", "PhaseMonitor", "move_joints", "to_pregrasp"]

#: Contact force (N) between the robot and the table / another object that counts as a collision.
COLLISION_FORCE = 15.0
#: Fingertip-table contact force (N) at which the approach stops (a guarded move) and the gripper closes.
GUARD_FORCE = 3.0

class Collision(Exception):
    pass


class TableTouch(Exception):
    """The fingertips touched the table during the approach: a guarded approach stops there."""


class PhaseMonitor:
    """Per control period: collision checks for the current phase and the optional recorder."""

    def __init__(self, task: GraspTask, recorder: EpisodeRecorder | None) -> None:
        self.task = task = as_task(task)
        self.recorder = recorder
        self.phase = "free"
        self.note = ""
        self._force = np.zeros(6)
        ids = task.ids
        self._robot = ids.robot_geoms
        self._fingers = ids.finger_geoms
        self._table = np.array([g for g in range(task.model.ngeom) if (mujoco.mj_id2name(
            task.model, mujoco.mjtObj.mjOBJ_GEOM, g) or "").startswith("table")])

    def __call__(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        if self.recorder is not None:
            self.recorder()
        if self.phase in ("free", "descent", "approach"):
            self._check(model, data)

    def _check(self, model: mujoco.MjModel, data: mujoco.MjData) -> None:
        n = data.ncon
        if n == 0:
            return
        geoms = np.asarray(data.contact.geom[:n])
        robot = np.isin(geoms, self._robot)
        cand = robot[:, 0] ^ robot[:, 1]
        if self.phase == "approach":
            cand &= ~np.isin(geoms, self.task.target_geoms).any(axis=1)
        for i in np.flatnonzero(cand):
            mujoco.mj_contactForce(model, data, int(i), self._force)
            if (self.phase == "approach" and np.isin(geoms[i], self._fingers).any()
                    and np.isin(geoms[i], self._table).any() and abs(self._force[0]) > GUARD_FORCE):
                raise TableTouch()
            if abs(self._force[0]) > COLLISION_FORCE or self.phase != "approach" and np.isin(
                    geoms[i], self.task.target_geoms).any():
                a, b = (mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, int(g)) or f"geom {int(g)}"
                        for g in geoms[i])
                raise Collision(f"{self.phase}: {a} - {b}, {abs(self._force[0]):.1f} N")


def move_joints(task: GraspTask, q_goal: np.ndarray, monitor: PhaseMonitor, joint_speed: float = 1.0,
                 settle: float = 0.5) -> None:
    """Minimum-jerk joint-space motion of the arm to ``q_goal`` (rad), then hold until at rest."""
    task = as_task(task)
    m, d, ids = task.model, task.data, task.ids
    q0 = d.ctrl[ids.arm_actuators].copy()
    duration = max(0.5, float(np.abs(q_goal - q0).max()) / joint_speed * 1.875)  # peak speed of min-jerk
    n = max(1, int(round(duration / CONTROL_DT)))
    lead = task.servo_lead
    q_prev = q0
    for k in range(1, n + 1):
        q = q0 + min_jerk(k / n) * (q_goal - q0)
        d.ctrl[ids.arm_actuators] = q + lead * (q - q_prev) / CONTROL_DT
        q_prev = q
        task.advance(CONTROL_DT)
        monitor(m, d)
    d.ctrl[ids.arm_actuators] = q_goal
    for _ in range(int(round(settle / CONTROL_DT))):
        if np.abs(d.qvel[ids.arm_dof]).max() < 0.01 and np.abs(d.qpos[ids.arm_qpos] - q_goal).max() < 2e-3:
            break
        task.advance(CONTROL_DT)
        monitor(m, d)


def to_pregrasp(task: GraspTask, plan: GraspPlan, monitor: PhaseMonitor) -> np.ndarray:
    """Open the gripper and move the TCP straight to above the pre-grasp pose, then down to it; returns the
    joint command (7,) rad. Raises :class:`Collision` / :class:`UnreachableError` as the monitor and IK do."""
    m, d, ids = task.model, task.data, task.ids
    monitor.phase = "free"
    set_gripper(d, ids, plan.open_width)
    # A straight line from the observation pose (high above the table) to above the pre-grasp keeps the
    # hand over the objects; joint-space interpolation could swing it through them.
    start = tcp_pose(d, ids)
    dist = float(np.linalg.norm(plan.above.t - start.t))
    q = move_to(m, d, ids, plan.above, max(1.0, dist / 0.2), q_ref=d.ctrl[ids.arm_actuators].copy(),
                settle=0.3, callback=monitor)
    monitor.phase = "descent"
    if float(np.linalg.norm(plan.above.t - plan.pregrasp.t)) > 1e-4:
        dist = float(np.linalg.norm(plan.above.t - plan.pregrasp.t))
        q = move_to(m, d, ids, plan.pregrasp, max(0.5, dist / 0.15), q_ref=q, settle=0.3, callback=monitor)
    return q


