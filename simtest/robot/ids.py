"""Ids of an attached Panda: element names in the caller's spec (:class:`PandaHandles`) resolved in a compiled
model (:class:`PandaIds`)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

import simtest  # noqa: F401  (selects the GL backend before mujoco is imported)
import mujoco

from simtest.camera import CameraModel
from simtest.errors import ConfigError

__all__ = ["PandaHandles", "PandaIds"]


@dataclass(frozen=True)
class PandaIds:
    """Indices of the Panda inside one compiled model.

    Attributes:
        arm_qpos: qpos addresses of joints 1..7 (7,).
        arm_dof: dof (qvel) addresses of joints 1..7 (7,).
        arm_actuators: Actuator ids of joints 1..7 (7,); ``ctrl`` is the joint target, rad.
        arm_limits: Joint limits (7, 2), rad.
        gripper_actuator: Actuator id of the gripper; ``ctrl`` is the commanded pad gap, m.
        finger_qpos: qpos addresses of the two finger slides (2,).
        finger_dof: dof addresses of the two finger slides (2,).
        tcp_site: Site id of the TCP (gripper frame, see :mod:`simtest.robot`).
        camera: Camera id of the wrist camera, -1 if there is none.
        finger_geoms: Collision geom ids of both fingers.
        robot_geoms: Collision geom ids of the whole robot.
        hand_body: Body id of the hand (link 7, which carries the hand, the TCP and the camera).
        base_body: Body id of the base (link 0).
        robot_bodies: Body ids of all robot bodies.
        wrist_camera: Intrinsics and size of the wrist camera (pose unset), or ``None``.
    """

    arm_qpos: np.ndarray
    arm_dof: np.ndarray
    arm_actuators: np.ndarray
    arm_limits: np.ndarray
    gripper_actuator: int
    finger_qpos: np.ndarray
    finger_dof: np.ndarray
    tcp_site: int
    camera: int
    finger_geoms: np.ndarray
    robot_geoms: np.ndarray
    hand_body: int
    base_body: int
    robot_bodies: np.ndarray
    wrist_camera: CameraModel | None

    def arm_q(self, data: mujoco.MjData) -> np.ndarray:
        """Current arm joint angles (7,), rad."""
        return data.qpos[self.arm_qpos].copy()


@dataclass(frozen=True)
class PandaHandles:
    """Names of the attached Panda's elements in the caller's spec; :meth:`bind` resolves ids.

    Attributes:
        prefix: Name prefix given at attachment.
        arm_joints, finger_joints, arm_actuators: Element names (prefixed).
        gripper_actuator, tcp_site, hand_body, base_body: Element names (prefixed).
        camera: Wrist camera name, or ``None``.
        finger_bodies: The two finger body names.
        wrist_camera: The camera model used for the wrist camera, or ``None``.
    """

    prefix: str
    arm_joints: tuple[str, ...]
    finger_joints: tuple[str, ...]
    arm_actuators: tuple[str, ...]
    gripper_actuator: str
    tcp_site: str
    hand_body: str
    base_body: str
    finger_bodies: tuple[str, ...]
    camera: str | None
    wrist_camera: CameraModel | None = field(default=None)

    def bind(self, model: mujoco.MjModel) -> PandaIds:
        """Resolve the names in a compiled model.

        Raises:
            ConfigError: If an element is missing (the model was not built from a spec with this Panda).
        """
        def _id(kind: mujoco.mjtObj, name: str) -> int:
            i = mujoco.mj_name2id(model, kind, name)
            if i < 0:
                raise ConfigError(f"model has no {kind.name[6:].lower()} named {name!r}; "
                                  f"was the Panda attached with prefix {self.prefix!r}?")
            return i

        J = mujoco.mjtObj.mjOBJ_JOINT
        joints = [_id(J, n) for n in self.arm_joints]
        fingers = [_id(J, n) for n in self.finger_joints]
        base = _id(mujoco.mjtObj.mjOBJ_BODY, self.base_body)
        # Robot bodies: the base's subtree.
        bodies = [b for b in range(model.nbody) if _is_descendant(model, b, base)]
        finger_bodies = [_id(mujoco.mjtObj.mjOBJ_BODY, n) for n in self.finger_bodies]
        collidable = (model.geom_contype != 0) | (model.geom_conaffinity != 0)
        robot_geoms = np.flatnonzero(np.isin(model.geom_bodyid, bodies) & collidable)
        finger_geoms = np.flatnonzero(np.isin(model.geom_bodyid, finger_bodies) & collidable)
        return PandaIds(
            arm_qpos=np.array([model.jnt_qposadr[j] for j in joints]),
            arm_dof=np.array([model.jnt_dofadr[j] for j in joints]),
            arm_actuators=np.array([_id(mujoco.mjtObj.mjOBJ_ACTUATOR, n) for n in self.arm_actuators]),
            arm_limits=np.array([model.jnt_range[j] for j in joints]),
            gripper_actuator=_id(mujoco.mjtObj.mjOBJ_ACTUATOR, self.gripper_actuator),
            finger_qpos=np.array([model.jnt_qposadr[j] for j in fingers]),
            finger_dof=np.array([model.jnt_dofadr[j] for j in fingers]),
            tcp_site=_id(mujoco.mjtObj.mjOBJ_SITE, self.tcp_site),
            camera=-1 if self.camera is None else _id(mujoco.mjtObj.mjOBJ_CAMERA, self.camera),
            finger_geoms=finger_geoms,
            robot_geoms=robot_geoms,
            hand_body=_id(mujoco.mjtObj.mjOBJ_BODY, self.hand_body),
            base_body=base,
            robot_bodies=np.array(bodies),
            wrist_camera=self.wrist_camera,
        )


def _is_descendant(model: mujoco.MjModel, body: int, root: int) -> bool:
    while body > 0:
        if body == root:
            return True
        body = int(model.body_parentid[body])
    return root == 0
