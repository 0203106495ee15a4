"""The Franka Emika Panda arm with a wrist RGB-D camera, used by dataset generation and the grasp env.

Modules, each owning one concern:

* :mod:`.asset` — the MJCF from the ``gymnasium-robotics`` wheel, its adaptation and :func:`attach_panda`;
  the robot's constants (:data:`HOME_QPOS`, :data:`T_TCP_CAM`, gripper geometry and gains).
* :mod:`.ids` — :class:`PandaHandles` (names in the caller's spec) and :class:`PandaIds` (bound ids).
* :mod:`.state` — TCP and wrist-camera poses, gripper commands, :func:`reset_arm`, :func:`step_for`.
* :mod:`.poses` — pose errors and interpolation of the motions.
* :mod:`.ik` — :class:`DiffIK`, the one damped least-squares solver: :func:`solve_ik`, :func:`ik_step`,
  :func:`is_reachable` and the env's fast control step.
* :mod:`.motion` — :func:`min_jerk` timing and :func:`move_to`.
* :mod:`.grasp` — the scripted grasp (:func:`grasp_and_lift`) and the phases the closed-loop episodes share.
* :mod:`.views` — :func:`sample_wrist_views`.

Frames (all poses are ``T_world_x``: frame ``x`` in the world, metres):

* **Gripper / TCP frame** (the grasp convention used everywhere in simtest): origin at the TCP, the centre
  between the distal finger pads (2.2 cm behind the fingertips, on the fingers' symmetry axis);
  **z = approach direction** (from the palm toward the object); **y = finger closing axis** (the left
  finger opens along +y); **x = y cross z**. A grasp pose is the pose this frame must reach, and the
  object is held between the pads along y.
* **Wrist camera** (OpenCV: x right, y down, z forward): optical axis parallel to the approach axis z,
  image x along the closing axis y, mounted on the hand beside the fingers at ``T_tcp_cam`` (see
  :data:`T_TCP_CAM`): 6.5 cm off the finger plane along the gripper's x axis and 9 cm behind the TCP,
  like a RealSense on a Panda hand. The fingers sit just below the bottom edge of the default view
  (they are 30 deg off-axis; the D435-like camera's vertical half field of view is 21 deg).
"""

from simtest.robot.asset import (
    ARM_JOINT_LIMITS,
    GRIPPER_CLOSED,
    GRIPPER_FORCE,
    GRIPPER_KP,
    GRIPPER_OPEN,
    HOME_QPOS,
    T_LINK7_TCP,
    T_TCP_CAM,
    TCP_TO_FINGERTIP,
    attach_panda,
    configure_physics,
    panda_asset_dir,
)
from simtest.robot.grasp import GraspResult, approach, close_and_wait, grasp_and_lift, lift_to, symmetric_grasp
from simtest.robot.ids import PandaHandles, PandaIds
from simtest.robot.ik import DiffIK, IKResult, UnreachableError, ik_step, is_reachable, solve_ik
from simtest.robot.motion import min_jerk, move_to
from simtest.robot.poses import rotvec_to_matrix
from simtest.robot.state import (
    camera_to_tcp_target,
    close_gripper,
    gripper_width,
    open_gripper,
    release_scratch,
    reset_arm,
    servo_lead,
    set_gripper,
    step_for,
    tcp_pose,
    wrist_camera_model,
)
from simtest.robot.views import sample_wrist_views

__all__ = [
    "ARM_JOINT_LIMITS",
    "DiffIK",
    "GRIPPER_CLOSED",
    "GRIPPER_FORCE",
    "GRIPPER_KP",
    "GRIPPER_OPEN",
    "GraspResult",
    "HOME_QPOS",
    "IKResult",
    "PandaHandles",
    "PandaIds",
    "T_LINK7_TCP",
    "T_TCP_CAM",
    "TCP_TO_FINGERTIP",
    "UnreachableError",
    "approach",
    "attach_panda",
    "camera_to_tcp_target",
    "close_and_wait",
    "close_gripper",
    "configure_physics",
    "grasp_and_lift",
    "gripper_width",
    "ik_step",
    "is_reachable",
    "lift_to",
    "min_jerk",
    "move_to",
    "open_gripper",
    "panda_asset_dir",
    "release_scratch",
    "reset_arm",
    "rotvec_to_matrix",
    "sample_wrist_views",
    "servo_lead",
    "set_gripper",
    "solve_ik",
    "step_for",
    "symmetric_grasp",
    "tcp_pose",
    "wrist_camera_model",
]
