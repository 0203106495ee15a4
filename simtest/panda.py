"""Franka Emika Panda arm with a wrist RGB-D camera: model attachment, inverse kinematics, scripted grasps.

The robot model (meshes, kinematic chain, joint limits, arm actuator gains) comes from the MJCF shipped
in the ``gymnasium-robotics`` wheel (``envs/assets/kitchen_franka/franka_assets``, Apache-2.0). It is read
into a :class:`mujoco.MjSpec`, adapted (see below) and attached into a caller's scene spec with
:func:`attach_panda`.

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

Gripper geometry: the pads are 2.2 cm long beyond the TCP (:data:`TCP_TO_FINGERTIP`), so a grasp centred
lower than that above a support surface pushes the fingertips into it; the largest pad gap is
:data:`GRIPPER_OPEN` (0.08 m).

Changes to the source model, and why:

* Gravity compensation (``gravcomp = 1``) on every robot body, as the real Panda's controller does, so
  the position servos track without steady-state sag.
* The two independent finger actuators are replaced by one position actuator on a fixed tendon
  ``q_left + q_right`` (its length is the gap between the pads in metres, 0 = closed, 0.08 = open) and
  an equality constraint keeping the fingers symmetric, like the real gripper's mechanical coupling.
  ``kp`` = :data:`GRIPPER_KP` N/m, grip force limited to :data:`GRIPPER_FORCE` N per finger (the real
  gripper holds 70 N continuously). Finger joint damping 200 N s/m and armature 0.1 kg (source: 100 and
  5): at the force limit each finger moves at about 0.15 m/s, so the gripper closes across 8 cm in
  about 0.3 s without knocking light objects away.
* Finger collision geoms: friction ``(1.5, 0.01, 0.0001)`` (sliding, torsional, rolling), ``condim=4``
  (torsional friction resists the object pivoting about the closing axis; rolling friction is not
  needed), ``solref=(0.005, 1)`` and ``solimp=(0.95, 0.99, 0.001)`` (stiff contacts: the pads sink
  about 0.2 mm into a gripped object), ``margin=0``, and ``priority=1`` so these parameters win over
  the object's when MuJoCo combines the two geoms' contact parameters. With 2 x 30 N normal force and
  friction 1.5 the grasp can carry about 9 kg before slipping, far above the objects in simtest.
  The arm links keep the source's collision parameters.
* Actuator user data of the source model is dropped (it needs ``nuser_actuator`` in the parent).
* A TCP site (``tcp``) and the wrist camera are added to the last link; the hand is part of link 7.

Recommended physics options (set by :func:`configure_physics`, called by :func:`attach_panda` unless told
not to): timestep 0.002 s, ``implicitfast`` integrator, elliptic friction cones with ``impratio = 10``.
"""

from __future__ import annotations

import importlib.util
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, NamedTuple

import numpy as np
from scipy.spatial.transform import Rotation

import simtest  # noqa: F401  (selects the GL backend before mujoco is imported)
import mujoco

from simtest.camera import CameraModel, look_at_pose
from simtest.errors import AssetError, ConfigError
from simtest.geometry import Pose

__all__ = [
    "ARM_JOINT_LIMITS",
    "GRIPPER_CLOSED",
    "GRIPPER_FORCE",
    "GRIPPER_KP",
    "GRIPPER_OPEN",
    "GraspResult",
    "HOME_QPOS",
    "IKResult",
    "PandaHandles",
    "PandaIds",
    "T_TCP_CAM",
    "T_LINK7_TCP",
    "TCP_TO_FINGERTIP",
    "UnreachableError",
    "attach_panda",
    "benchmark",
    "camera_to_tcp_target",
    "close_gripper",
    "configure_physics",
    "grasp_and_lift",
    "gripper_width",
    "ik_step",
    "is_reachable",
    "move_to",
    "open_gripper",
    "panda_asset_dir",
    "release_scratch",
    "reset_arm",
    "set_gripper",
    "solve_ik",
    "sample_wrist_views",
    "step_for",
    "symmetric_grasp",
    "tcp_pose",
    "wrist_camera_model",
]

# --- constants ----------------------------------------------------------------------------------------

_SOURCE_ARM_JOINTS = tuple(f"robot:panda0_joint{i}" for i in range(1, 8))
_SOURCE_FINGER_JOINTS = ("robot:panda0_finger_joint1", "robot:panda0_finger_joint2")
_SOURCE_ARM_ACTUATORS = tuple(f"panda0_joint{i}" for i in range(1, 8))
_SOURCE_FINGER_ACTUATORS = ("r_gripper_finger_joint", "l_gripper_finger_joint")
_SOURCE_BASE_BODY = "panda0_link0"
_SOURCE_HAND_BODY = "panda0_link7"
_SOURCE_FINGER_BODIES = ("panda0_leftfinger", "panda0_rightfinger")

#: Arm joint limits of the model (rad), rows = joints 1..7, columns = (lower, upper).
ARM_JOINT_LIMITS = np.array([
    [-2.8973, 2.8973], [-1.7628, 1.7628], [-2.8973, 2.8973], [-3.0718, -0.4],
    [-2.8973, 2.8973], [-1.6573, 2.1127], [-2.8973, 2.8973],
])

#: Ready posture (rad, joints 1..7): the TCP 0.45 m in front of the base and 0.40 m above it, approach
#: axis straight down, closing axis along the base's -y axis (x along the base's +x). Found by IK from a
#: bent-elbow posture; every joint is far from its limits.
HOME_QPOS = np.array([0.0, -0.348, 0.0, -2.182, 0.0, 0.264, 0.0])

#: The source finger body frame (and the TCP frame) relative to link 7: -45 deg about z.
_Q_LINK7_FINGER_WXYZ = np.array([0.92388, 0.0, 0.0, -0.382683])
#: Finger body origin along link 7's z (m), and the TCP along the finger axis from there (m).
_FINGER_Z = 0.1654
_TCP_IN_FINGER_Z = 0.0725
#: Pose of the TCP (gripper) frame in link 7: the finger frame orientation, at the distal pad centre.
T_LINK7_TCP = Pose.from_quat_wxyz(_Q_LINK7_FINGER_WXYZ / np.linalg.norm(_Q_LINK7_FINGER_WXYZ),
                                  [0.0, 0.0, _FINGER_Z + _TCP_IN_FINGER_Z])
#: Pose of the wrist camera (OpenCV frame) in the TCP frame: image x = closing axis y, image y = -x,
#: optical axis = approach z; 6.5 cm along +x off the finger plane, 9 cm behind the TCP.
T_TCP_CAM = Pose(np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]), [0.065, 0.0, -0.09])

#: Distance from the TCP to the fingertips along the approach axis, m.
TCP_TO_FINGERTIP = 0.022

#: Gripper commands: the gap between the finger pads (m).
GRIPPER_OPEN = 0.08
GRIPPER_CLOSED = 0.0
#: Gripper position gain (N per m of gap error) and force limit per finger (N). A commanded gap of 0 on
#: an object wider than 1 cm saturates at the force limit.
GRIPPER_KP = 3000.0
GRIPPER_FORCE = 30.0

#: Finger contact parameters (see the module docstring).
FINGER_FRICTION = (1.5, 0.01, 0.0001)
FINGER_CONDIM = 4
FINGER_SOLREF = (0.005, 1.0)
FINGER_SOLIMP = (0.95, 0.99, 0.001, 0.5, 2.0)


class UnreachableError(ConfigError):
    """A target pose has no inverse-kinematics solution within tolerance."""


class IKResult(NamedTuple):
    """Inverse kinematics outcome.

    Attributes:
        q: Arm joint angles (7,), rad, within the joint limits.
        success: Whether both residuals are within tolerance.
        pos_err: Position residual of the target frame, m.
        rot_err: Orientation residual (angle of the rotation error), rad.
    """

    q: np.ndarray
    success: bool
    pos_err: float
    rot_err: float


@dataclass(frozen=True)
class GraspResult:
    """Outcome of :func:`grasp_and_lift`.

    Attributes:
        success: The object is at least ``success_height`` above its resting height after the hold.
        reason: ``"ok"``, ``"unreachable"`` (IK failed for a waypoint), ``"empty"`` (the gripper closed on
            nothing) or ``"dropped"`` (the object is not high enough after the hold).
        object_rise: Height gain of the object after the hold, m.
        gripper_width: Gap between the finger pads after the hold, m.
        sim_time: Simulated time spent, s.
    """

    success: bool
    reason: str
    object_rise: float
    gripper_width: float
    sim_time: float

    def __bool__(self) -> bool:
        return self.success


# --- asset loading --------------------------------------------------------------------------------------

def panda_asset_dir() -> Path:
    """The folder of the Panda MJCF inside the installed ``gymnasium-robotics`` wheel.

    Raises:
        AssetError: If the wheel is not installed or the folder lacks the expected files.
    """
    spec = importlib.util.find_spec("gymnasium_robotics")  # found without importing (its import prints)
    if spec is None or not spec.submodule_search_locations:
        raise AssetError("the Panda model needs the 'gymnasium-robotics' package, which is not installed "
                         "(pip install gymnasium-robotics)")
    root = Path(list(spec.submodule_search_locations)[0])
    folder = root / "envs" / "assets" / "kitchen_franka" / "franka_assets"
    missing = [f for f in ("chain.xml", "assets.xml", "actuator.xml", "meshes") if not (folder / f).exists()]
    if missing:
        raise AssetError(f"Panda model folder {folder} lacks {missing}; expected chain.xml, assets.xml, "
                         "actuator.xml and meshes/ from gymnasium-robotics")
    return folder


def _load_source_spec() -> mujoco.MjSpec:
    folder = panda_asset_dir()
    # The source files are <mujocoinclude> fragments meant for <include>; this root only includes them.
    xml = (f'<mujoco model="panda"><include file="{folder / "assets.xml"}"/>'
           f'<include file="{folder / "actuator.xml"}"/>'
           f'<worldbody><include file="{folder / "chain.xml"}"/></worldbody></mujoco>')
    try:
        spec = mujoco.MjSpec.from_string(xml)
    except ValueError as exc:
        raise AssetError(f"could not parse the Panda model in {folder}: {exc}") from exc
    # Includes rewrite mesh paths relative to the including folder; point them into meshes/ absolutely
    # so they resolve wherever the spec is attached.
    for mesh in spec.meshes:
        mesh.file = str(folder / "meshes" / Path(mesh.file).relative_to(folder))
    return spec


def _build_panda_spec(wrist_camera: CameraModel | None) -> mujoco.MjSpec:
    spec = _load_source_spec()
    for attr in ("nuser_actuator", "nuser_geom", "nuser_body", "nuser_jnt", "nuser_site"):
        setattr(spec, attr, -1)  # the parent decides; the source's actuator user data is dropped below
    for act in list(spec.actuators):
        act.userdata = []
    for name in _SOURCE_FINGER_ACTUATORS:
        spec.delete(spec.actuator(name))
    for body in spec.bodies:
        body.gravcomp = 1.0
    for geom in spec.geoms:
        geom.userdata = []

    # Finger pads: named, stiff, high-friction contacts.
    for body_name, side in zip(_SOURCE_FINGER_BODIES, ("left", "right")):
        body = spec.body(body_name)
        k = 0
        for geom in body.geoms:
            if geom.contype == 0 and geom.conaffinity == 0:
                continue  # visual mesh
            geom.name = f"{side}_pad{k}"
            k += 1
            geom.friction = list(FINGER_FRICTION)
            geom.condim = FINGER_CONDIM
            geom.solref = list(FINGER_SOLREF)
            geom.solimp = list(FINGER_SOLIMP)
            geom.priority = 1
            geom.margin = 0.0

    # Coupled gripper: a tendon measuring the pad gap, an equality keeping the fingers symmetric.
    tendon = spec.add_tendon()
    tendon.name = "gripper_gap"
    tendon.wrap_joint(_SOURCE_FINGER_JOINTS[0], 1.0)
    tendon.wrap_joint(_SOURCE_FINGER_JOINTS[1], 1.0)
    eq = spec.add_equality()
    eq.name = "finger_coupling"
    eq.type = mujoco.mjtEq.mjEQ_JOINT
    eq.objtype = mujoco.mjtObj.mjOBJ_JOINT
    eq.name1 = _SOURCE_FINGER_JOINTS[1]
    eq.name2 = _SOURCE_FINGER_JOINTS[0]
    eq.data[:5] = [0.0, 1.0, 0.0, 0.0, 0.0]
    eq.solref = [0.005, 1.0]
    act = spec.add_actuator()
    act.name = "gripper"
    act.set_to_position(kp=GRIPPER_KP, kv=0.0)
    act.trntype = mujoco.mjtTrn.mjTRN_TENDON
    act.target = "gripper_gap"
    act.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
    act.ctrlrange = [GRIPPER_CLOSED, GRIPPER_OPEN]
    act.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
    act.forcerange = [-GRIPPER_FORCE, GRIPPER_FORCE]
    for name in _SOURCE_FINGER_JOINTS:
        joint = spec.joint(name)
        joint.damping = [200.0, 0.0, 0.0]
        joint.armature = 0.1

    hand = spec.body(_SOURCE_HAND_BODY)
    tcp = hand.add_site()
    tcp.name = "tcp"
    tcp.pos = T_LINK7_TCP.t.tolist()
    tcp.quat = T_LINK7_TCP.quat_wxyz().tolist()
    tcp.size = [0.005, 0.005, 0.005]
    tcp.group = 4
    tcp.rgba = [1.0, 0.2, 0.2, 1.0]

    if wrist_camera is not None:
        T_link7_cam = T_LINK7_TCP @ T_TCP_CAM
        pos, R = wrist_camera.with_pose(T_link7_cam).mujoco_pose()  # the OpenCV->MuJoCo flip
        cam = hand.add_camera()
        cam.name = "wrist_camera"
        cam.pos = pos.tolist()
        cam.quat = Pose(R, pos).quat_wxyz().tolist()
        intr = wrist_camera.mujoco_intrinsics()
        cam.resolution = intr["resolution"]
        cam.focal_pixel = intr["focal_pixel"]
        cam.principal_pixel = intr["principal_pixel"]
        cam.sensor_size = intr["sensor_size"]
        # Visual-only camera housing (D435: 90 x 25 x 25 mm), behind the optical centre, long side along
        # the image x axis; it never enters the camera's own view.
        housing = hand.add_geom()
        housing.name = "wrist_camera_housing"
        housing.type = mujoco.mjtGeom.mjGEOM_BOX
        housing.size = [0.045, 0.0125, 0.0125]
        housing_pose = T_link7_cam @ Pose(np.eye(3), [0.0, 0.0, -0.014])
        housing.pos = housing_pose.t.tolist()
        housing.quat = housing_pose.quat_wxyz().tolist()
        housing.contype = 0
        housing.conaffinity = 0
        housing.mass = 0.0
        housing.rgba = [0.15, 0.15, 0.17, 1.0]
        housing.group = 1
    return spec


def configure_physics(spec: mujoco.MjSpec, timestep: float = 0.002) -> None:
    """Set the physics options the Panda's controllers and grasps were tuned with.

    Args:
        spec: The scene spec (modified in place).
        timestep: Physics step, s (500 Hz by default).
    """
    if not timestep > 0:
        raise ConfigError(f"timestep must be > 0 s, got {timestep!r}")
    spec.option.timestep = float(timestep)
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.option.cone = mujoco.mjtCone.mjCONE_ELLIPTIC
    spec.option.impratio = 10.0


# --- handles and ids --------------------------------------------------------------------------------------

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
        tcp_site: Site id of the TCP (gripper frame, see the module docstring).
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


def attach_panda(
    spec: mujoco.MjSpec,
    base_pose: Pose = Pose.identity(),
    prefix: str = "panda/",
    wrist_camera: CameraModel | None = CameraModel.default(640, 480),
    *,
    physics: bool = True,
) -> PandaHandles:
    """Attach a Panda (arm, coupled gripper, TCP site, wrist camera) into ``spec``.

    Args:
        spec: The caller's scene spec (table, objects, ...), modified in place.
        base_pose: ``T_world_base``: pose of the robot base (link 0 origin, on its mounting surface), m.
        prefix: Prefix of every attached element name; must be non-empty and unused in ``spec``.
        wrist_camera: Intrinsics and image size of the wrist camera (its pose is ignored; the mount is
            :data:`T_TCP_CAM`), or ``None`` for no camera. Default: D435-like 640x480, fx = fy = 615 px.
        physics: Also apply :func:`configure_physics` to ``spec`` (timestep 0.002 s, implicitfast,
            elliptic cones, impratio 10), the options the controllers and grasps were tuned with.

    Returns:
        Names of the attached elements; call :meth:`PandaHandles.bind` on the compiled model.

    Raises:
        ConfigError: If ``prefix`` is empty or already used by an element of ``spec``.
        AssetError: If the Panda model cannot be found or parsed.
    """
    if not prefix:
        raise ConfigError("prefix must be a non-empty string such as 'panda/', got ''")
    if spec.body(prefix + _SOURCE_BASE_BODY) is not None:
        raise ConfigError(f"spec already has a body {prefix + _SOURCE_BASE_BODY!r}; choose another prefix "
                          f"than {prefix!r}")
    child = _build_panda_spec(wrist_camera)
    frame = spec.worldbody.add_frame()
    frame.pos = np.asarray(base_pose.t).tolist()
    frame.quat = base_pose.quat_wxyz().tolist()
    spec.attach(child, prefix=prefix, frame=frame)
    if physics:
        configure_physics(spec)
    if wrist_camera is not None:
        vis = spec.visual.global_
        vis.offwidth = max(int(vis.offwidth), wrist_camera.width)
        vis.offheight = max(int(vis.offheight), wrist_camera.height)
    return PandaHandles(
        prefix=prefix,
        arm_joints=tuple(prefix + n for n in _SOURCE_ARM_JOINTS),
        finger_joints=tuple(prefix + n for n in _SOURCE_FINGER_JOINTS),
        arm_actuators=tuple(prefix + n for n in _SOURCE_ARM_ACTUATORS),
        gripper_actuator=prefix + "gripper",
        tcp_site=prefix + "tcp",
        hand_body=prefix + _SOURCE_HAND_BODY,
        base_body=prefix + _SOURCE_BASE_BODY,
        finger_bodies=tuple(prefix + n for n in _SOURCE_FINGER_BODIES),
        camera=None if wrist_camera is None else prefix + "wrist_camera",
        wrist_camera=wrist_camera,
    )


# --- state helpers ----------------------------------------------------------------------------------------

def tcp_pose(data: mujoco.MjData, ids: PandaIds) -> Pose:
    """``T_world_tcp`` from the last kinematics pass on ``data`` (m)."""
    return Pose(data.site_xmat[ids.tcp_site].reshape(3, 3), data.site_xpos[ids.tcp_site])


def wrist_camera_model(data: mujoco.MjData, ids: PandaIds) -> CameraModel:
    """The wrist camera's :class:`CameraModel` with its world pose from the last forward pass.

    ``data.cam_xpos`` / ``cam_xmat`` are filled by ``mj_forward`` / ``mj_step`` (or ``mj_kinematics``
    followed by ``mj_camlight``).

    Raises:
        ConfigError: If the Panda was attached without a wrist camera.
    """
    if ids.camera < 0 or ids.wrist_camera is None:
        raise ConfigError("this Panda has no wrist camera (attach_panda(..., wrist_camera=None))")
    cam = ids.wrist_camera
    return CameraModel.from_mujoco(data.cam_xpos[ids.camera], data.cam_xmat[ids.camera], cam.K, cam.width,
                                   cam.height)


def camera_to_tcp_target(T_world_cam: Pose) -> Pose:
    """The TCP pose that puts the wrist camera (OpenCV frame) at ``T_world_cam``."""
    return T_world_cam @ T_TCP_CAM.inverse()


def gripper_width(data: mujoco.MjData, ids: PandaIds) -> float:
    """Current gap between the finger pads, m (0 = closed, 0.08 = fully open)."""
    return float(data.qpos[ids.finger_qpos].sum())


def set_gripper(data: mujoco.MjData, ids: PandaIds, width: float) -> None:
    """Command the pad gap, m, clipped to [:data:`GRIPPER_CLOSED`, :data:`GRIPPER_OPEN`].

    Commanding a gap smaller than an object squeezes it with up to :data:`GRIPPER_FORCE` N per finger.
    """
    data.ctrl[ids.gripper_actuator] = float(np.clip(width, GRIPPER_CLOSED, GRIPPER_OPEN))


def open_gripper(data: mujoco.MjData, ids: PandaIds) -> None:
    """Command the gripper fully open (0.08 m gap)."""
    set_gripper(data, ids, GRIPPER_OPEN)


def close_gripper(data: mujoco.MjData, ids: PandaIds) -> None:
    """Command the gripper closed (gap 0): grips any object between the pads at the force limit."""
    set_gripper(data, ids, GRIPPER_CLOSED)


def reset_arm(model: mujoco.MjModel, data: mujoco.MjData, ids: PandaIds,
              q: np.ndarray | None = None, gripper: float = GRIPPER_OPEN) -> None:
    """Teleport the arm to ``q`` (rad, default :data:`HOME_QPOS`) at rest, with matching commands.

    Also sets the fingers to the gap ``gripper`` (m) and runs ``mj_forward``.
    """
    q = HOME_QPOS if q is None else np.asarray(q, dtype=np.float64)
    _check_q(q, ids)
    data.qpos[ids.arm_qpos] = q
    data.qvel[ids.arm_dof] = 0.0
    data.ctrl[ids.arm_actuators] = q
    half = float(np.clip(gripper, GRIPPER_CLOSED, GRIPPER_OPEN)) / 2.0
    data.qpos[ids.finger_qpos] = half
    data.qvel[ids.finger_dof] = 0.0
    set_gripper(data, ids, gripper)
    mujoco.mj_forward(model, data)


def _check_q(q: np.ndarray, ids: PandaIds) -> None:
    if q.shape != (7,) or not np.all(np.isfinite(q)):
        raise ConfigError(f"arm configuration must be 7 finite joint angles (rad), got {q!r}")


def step_for(model: mujoco.MjModel, data: mujoco.MjData, duration: float) -> None:
    """Advance the physics by ``duration`` seconds (rounded to whole timesteps) with the current controls."""
    n = max(0, int(round(duration / model.opt.timestep)))
    mujoco.mj_step(model, data, n)


# --- inverse kinematics -----------------------------------------------------------------------------------

#: The scratch MjData of the last model IK ran on. One entry only: an MjData keeps its model alive, so every
#: cached entry pins a whole compiled model (tens of MB with its meshes) in memory.
_SCRATCH: dict[int, tuple[mujoco.MjModel, mujoco.MjData]] = {}


def release_scratch() -> None:
    """Drop the IK scratch data (and with it the reference to its model), e.g. before the model is freed."""
    _SCRATCH.clear()


def _scratch(model: mujoco.MjModel, data: mujoco.MjData) -> mujoco.MjData:
    """A scratch MjData for ``model`` (cached for the last model) holding ``data``'s current state."""
    entry = _SCRATCH.get(id(model))
    if entry is None or entry[0] is not model:
        _SCRATCH.clear()
        entry = (model, mujoco.MjData(model))
        _SCRATCH[id(model)] = entry
    scratch = entry[1]
    scratch.qpos[:] = data.qpos
    if model.nmocap:
        scratch.mocap_pos[:] = data.mocap_pos
        scratch.mocap_quat[:] = data.mocap_quat
    return scratch


def _pose_error(target: Pose, pos: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position error (3,) m and rotation error as a world-frame rotation vector (3,) rad."""
    e_p = target.t - pos
    e_r = Rotation.from_matrix(target.R @ R.T).as_rotvec()
    return e_p, e_r


def _dls(J: np.ndarray, e: np.ndarray, damping: float) -> np.ndarray:
    """Damped least-squares step ``J^T (J J^T + damping^2 I)^-1 e``."""
    JJt = J @ J.T
    JJt[np.diag_indices_from(JJt)] += damping ** 2
    return J.T @ np.linalg.solve(JJt, e)


def _ik_iterations(model: mujoco.MjModel, scratch: mujoco.MjData, ids: PandaIds, site: int, target: Pose,
                   q0: np.ndarray, posture: np.ndarray, *, max_iters: int, pos_tol: float, rot_tol: float,
                   damping: float, posture_gain: float, max_step: float) -> IKResult:
    lo, hi = ids.arm_limits[:, 0], ids.arm_limits[:, 1]
    q = np.clip(q0, lo, hi)
    jacp = np.zeros((3, model.nv))
    jacr = np.zeros((3, model.nv))
    pos_err = rot_err = np.inf
    for _ in range(max_iters + 1):
        scratch.qpos[ids.arm_qpos] = q
        mujoco.mj_kinematics(model, scratch)
        mujoco.mj_comPos(model, scratch)
        e_p, e_r = _pose_error(target, scratch.site_xpos[site], scratch.site_xmat[site].reshape(3, 3))
        pos_err, rot_err = float(np.linalg.norm(e_p)), float(np.linalg.norm(e_r))
        if pos_err <= pos_tol and rot_err <= rot_tol:
            return IKResult(q, True, pos_err, rot_err)
        mujoco.mj_jacSite(model, scratch, jacp, jacr, site)
        J = np.vstack([jacp[:, ids.arm_dof], jacr[:, ids.arm_dof]])
        e = np.concatenate([e_p, e_r])
        free = np.ones(7, dtype=bool)
        for _ in range(3):  # drop joints pinned at a limit and pushed beyond it, then re-solve
            Jf = J[:, free]
            dq_f = _dls(Jf, e, damping)
            null = np.eye(Jf.shape[1]) - np.linalg.pinv(Jf, rcond=1e-3) @ Jf
            dq_f = dq_f + null @ (posture_gain * (posture - q)[free])
            dq = np.zeros(7)
            dq[free] = dq_f
            pinned = ((q <= lo + 1e-9) & (dq < 0)) | ((q >= hi - 1e-9) & (dq > 0))
            if not np.any(pinned & free):
                break
            free &= ~pinned
        n = np.linalg.norm(dq)
        if n > max_step:
            dq *= max_step / n
        q = np.clip(q + dq, lo, hi)
    return IKResult(q, False, pos_err, rot_err)


def solve_ik(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    ids: PandaIds,
    target: Pose,
    q_init: np.ndarray | None = None,
    *,
    frame: str = "tcp",
    pos_tol: float = 5e-4,
    rot_tol: float = np.deg2rad(0.3),
    max_iters: int = 150,
    damping: float = 0.03,
    posture: np.ndarray | None = None,
    posture_gain: float = 0.05,
    restarts: int = 4,
    rng: np.random.Generator | None = None,
) -> IKResult:
    """Joint angles that put the TCP (or the wrist camera) at ``target``.

    Damped least squares on the site Jacobian, with joints clamped to their limits (joints pinned at a
    limit are dropped from the step) and a null-space pull toward ``posture``. Iterates on a scratch
    MjData: ``data`` is only read (the non-arm state, e.g. a free object's pose, is irrelevant to the arm).
    If the solve from ``q_init`` fails it is retried from ``posture`` and then, if ``rng`` is given, from
    ``restarts`` random configurations.

    Args:
        model: Compiled model containing the Panda.
        data: Current state; read only.
        ids: The Panda's ids (:meth:`PandaHandles.bind`).
        target: Desired ``T_world_tcp`` (``frame="tcp"``) or ``T_world_cam`` of the wrist camera in OpenCV
            convention (``frame="camera"``), m.
        q_init: Start configuration (7,) rad; default the current arm configuration in ``data``.
        frame: ``"tcp"`` or ``"camera"``.
        pos_tol: Position tolerance, m.
        rot_tol: Orientation tolerance, rad.
        max_iters: Iterations per attempt.
        damping: DLS damping (m, rad scale).
        posture: Preferred configuration (7,) rad; default :data:`HOME_QPOS`.
        posture_gain: Null-space pull toward ``posture`` per iteration (fraction of the offset).
        restarts: Random restarts (only with ``rng``).
        rng: Generator for random restarts; ``None`` disables them.

    Returns:
        The best :class:`IKResult` found: ``(q, success, pos_err m, rot_err rad)``.
    """
    if frame not in ("tcp", "camera"):
        raise ConfigError(f"frame must be 'tcp' or 'camera', got {frame!r}")
    if frame == "camera":
        target = camera_to_tcp_target(target)
    posture = HOME_QPOS if posture is None else np.asarray(posture, dtype=np.float64)
    q0 = ids.arm_q(data) if q_init is None else np.asarray(q_init, dtype=np.float64)
    _check_q(q0, ids)
    scratch = _scratch(model, data)
    kw = dict(max_iters=max_iters, pos_tol=pos_tol, rot_tol=rot_tol, damping=damping,
              posture_gain=posture_gain, max_step=0.5)
    starts = [q0, posture]
    if rng is not None:
        lo, hi = ids.arm_limits[:, 0], ids.arm_limits[:, 1]
        starts += [rng.uniform(lo, hi) for _ in range(restarts)]
    best: IKResult | None = None
    for start in starts:
        res = _ik_iterations(model, scratch, ids, ids.tcp_site, target, start, posture, **kw)
        if res.success:
            return res
        if best is None or res.pos_err + 0.1 * res.rot_err < best.pos_err + 0.1 * best.rot_err:
            best = res
    assert best is not None
    return best


def is_reachable(model: mujoco.MjModel, data: mujoco.MjData, ids: PandaIds, target: Pose,
                 q_init: np.ndarray | None = None, *, frame: str = "tcp", check_collisions: bool = False,
                 rng: np.random.Generator | None = None, **ik_kwargs) -> bool:
    """Whether IK reaches ``target`` (see :func:`solve_ik` for the arguments and tolerances).

    With ``check_collisions`` the solution must also be free of contacts between the robot and anything
    else (other robot links excluded) at the current state of the other bodies.
    """
    res = solve_ik(model, data, ids, target, q_init, frame=frame, rng=rng, **ik_kwargs)
    if not res.success:
        return False
    return not check_collisions or not _in_collision(model, data, ids, res.q)


def _in_collision(model: mujoco.MjModel, data: mujoco.MjData, ids: PandaIds, q: np.ndarray) -> bool:
    """Whether the robot at ``q`` touches anything (including itself) at the current state of the rest."""
    scratch = _scratch(model, data)
    scratch.qpos[ids.arm_qpos] = q
    mujoco.mj_fwdPosition(model, scratch)
    robot = set(ids.robot_geoms.tolist())
    for c in scratch.contact[: scratch.ncon]:
        if c.dist < 0.0 and (c.geom1 in robot or c.geom2 in robot):
            return True
    return False


def ik_step(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    ids: PandaIds,
    target_pose: Pose,
    dt: float,
    *,
    q_ref: np.ndarray | None = None,
    max_lin_speed: float = 0.3,
    max_ang_speed: float = 1.5,
    iters: int = 3,
    damping: float = 0.03,
    posture_gain: float = 0.02,
) -> np.ndarray:
    """One differential-IK control step toward ``target_pose`` (``T_world_tcp``, m).

    The TCP is moved from its pose at ``q_ref`` toward the target by at most ``max_lin_speed * dt`` (m)
    and ``max_ang_speed * dt`` (rad), and the joint targets for that intermediate pose are returned
    (a few DLS iterations, clamped to the joint limits). Feed them to the arm position actuators
    (``data.ctrl[ids.arm_actuators]``) and pass them back as ``q_ref`` next step to integrate the command
    rather than the lagging measured state.

    Args:
        model, data, ids: The model, its state (read only) and the Panda's ids.
        target_pose: Goal ``T_world_tcp``.
        dt: Control period, s (e.g. 0.05 for 20 Hz).
        q_ref: Configuration (7,) rad to step from; default the measured arm configuration.
        max_lin_speed: TCP speed limit, m/s.
        max_ang_speed: TCP angular speed limit, rad/s.

    Returns:
        Arm joint targets (7,), rad.
    """
    if not dt > 0:
        raise ConfigError(f"dt must be > 0 s, got {dt!r}")
    q = ids.arm_q(data) if q_ref is None else np.asarray(q_ref, dtype=np.float64)
    _check_q(q, ids)
    scratch = _scratch(model, data)
    scratch.qpos[ids.arm_qpos] = q
    mujoco.mj_kinematics(model, scratch)
    current = tcp_pose(scratch, ids)
    waypoint = _interpolate(current, target_pose, max_lin_speed * dt, max_ang_speed * dt)
    res = _ik_iterations(model, scratch, ids, ids.tcp_site, waypoint, q, HOME_QPOS, max_iters=iters,
                         pos_tol=1e-5, rot_tol=1e-4, damping=damping, posture_gain=posture_gain,
                         max_step=max(max_ang_speed * dt * 4.0, 0.05))
    return res.q


def _interpolate(a: Pose, b: Pose, max_dist: float, max_angle: float) -> Pose:
    """The pose from ``a`` toward ``b`` at most ``max_dist`` m and ``max_angle`` rad away."""
    dp = b.t - a.t
    rv = Rotation.from_matrix(b.R @ a.R.T).as_rotvec()
    dist, ang = float(np.linalg.norm(dp)), float(np.linalg.norm(rv))
    s = 1.0
    if dist > max_dist:
        s = min(s, max_dist / dist)
    if ang > max_angle:
        s = min(s, max_angle / ang)
    if s >= 1.0:
        return b
    return Pose(Rotation.from_rotvec(rv * s).as_matrix() @ a.R, a.t + dp * s)


def _lerp_pose(a: Pose, b: Pose, s: float) -> Pose:
    rv = Rotation.from_matrix(b.R @ a.R.T).as_rotvec()
    return Pose(Rotation.from_rotvec(rv * s).as_matrix() @ a.R, a.t + (b.t - a.t) * s)


# --- scripted motion ----------------------------------------------------------------------------------------

def move_to(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    ids: PandaIds,
    target: Pose,
    duration: float,
    *,
    path: str = "cartesian",
    control_dt: float = 0.05,
    settle: float = 1.0,
    settle_tol: tuple[float, float] = (1e-3, np.deg2rad(0.5)),
    gripper: float | None = None,
    q_ref: np.ndarray | None = None,
    callback: Callable[[mujoco.MjModel, mujoco.MjData], None] | None = None,
) -> np.ndarray:
    """Move the TCP to ``target`` (``T_world_tcp``, m) in ``duration`` seconds, then let it settle.

    The goal configuration is solved first (IK from the current command). With ``path="cartesian"`` the
    TCP follows a straight line (position) and a slerp (orientation) with minimum-jerk timing, re-solved
    with :func:`ik_step` every ``control_dt`` seconds; with ``path="joint"`` the joint targets move along
    a minimum-jerk straight line in joint space (for large free motions and reorientations). The servo
    targets get a velocity feed-forward ``(damping / kp) * qdot`` that cancels the lag of the position
    servos against the joint damping. The physics runs at the model's timestep in between. Afterwards
    the goal is held until the TCP is within ``settle_tol`` of the target and at rest, for at most
    ``settle`` seconds.

    Args:
        model, data, ids: Model, state (advanced in place) and the Panda's ids.
        target: Goal TCP pose in the world.
        duration: Motion time, s.
        path: ``"cartesian"`` or ``"joint"``.
        control_dt: Control period, s (0.05 = 20 Hz).
        settle: Longest time holding the goal after the motion, s.
        settle_tol: (position m, angle rad) at which settling stops early.
        gripper: If given, the pad gap command (m) during the motion; otherwise unchanged.
        q_ref: Arm command (7,) rad to start from; default the measured arm configuration. Pass the
            value returned by the previous call to chain motions without re-basing on the servo lag.
        callback: Called as ``callback(model, data)`` after every control period.

    Returns:
        The final arm command (7,), rad.

    Raises:
        ConfigError: On a bad ``path`` or ``duration``.
        UnreachableError: If IK cannot reach ``target`` (names the residual); nothing was simulated.
    """
    if path not in ("cartesian", "joint"):
        raise ConfigError(f"path must be 'cartesian' or 'joint', got {path!r}")
    if not duration >= 0:
        raise ConfigError(f"duration must be >= 0 s, got {duration!r}")
    q_cmd = ids.arm_q(data) if q_ref is None else np.asarray(q_ref, dtype=np.float64)
    _check_q(q_cmd, ids)
    goal = solve_ik(model, data, ids, target, q_cmd)
    if not goal.success:
        raise UnreachableError(
            f"TCP target at {np.round(target.t, 4).tolist()} m is out of reach: IK residual "
            f"{goal.pos_err * 1000:.1f} mm / {np.rad2deg(goal.rot_err):.2f} deg (tolerance 0.5 mm / 0.3 deg)")
    if gripper is not None:
        set_gripper(data, ids, gripper)
    scratch = _scratch(model, data)
    scratch.qpos[ids.arm_qpos] = q_cmd
    mujoco.mj_kinematics(model, scratch)
    start = tcp_pose(scratch, ids)
    q_start = q_cmd.copy()
    n_ctrl = max(1, int(round(duration / control_dt)))
    n_sub = max(1, int(round(control_dt / model.opt.timestep)))
    lead = _servo_lead(model, ids)
    for k in range(1, n_ctrl + 1):
        s = k / n_ctrl
        s = s ** 3 * (10 - 15 * s + 6 * s * s)  # minimum-jerk timing
        q_prev = q_cmd
        if path == "joint":
            q_cmd = q_start + s * (goal.q - q_start)
        else:
            q_cmd = ik_step(model, data, ids, _lerp_pose(start, target, s), control_dt, q_ref=q_cmd,
                            max_lin_speed=np.inf, max_ang_speed=np.inf)
        # Velocity feed-forward: a position servo against joint damping b lags by (b / kp) * qdot.
        data.ctrl[ids.arm_actuators] = q_cmd + lead * (q_cmd - q_prev) / control_dt
        mujoco.mj_step(model, data, n_sub)
        if callback is not None:
            callback(model, data)
    if path == "cartesian":  # land exactly on the goal, from the solution tracked along the path
        final = solve_ik(model, data, ids, target, q_cmd)
        q_cmd = final.q if final.success else goal.q
    else:
        q_cmd = goal.q
    data.ctrl[ids.arm_actuators] = q_cmd
    for _ in range(int(round(settle / control_dt))):
        e_p, e_r = _pose_error(target, data.site_xpos[ids.tcp_site],
                               data.site_xmat[ids.tcp_site].reshape(3, 3))
        if (np.linalg.norm(e_p) <= settle_tol[0] and np.linalg.norm(e_r) <= settle_tol[1]
                and np.abs(data.qvel[ids.arm_dof]).max() < 0.02):
            break
        mujoco.mj_step(model, data, n_sub)
        if callback is not None:
            callback(model, data)
    return q_cmd


def _servo_lead(model: mujoco.MjModel, ids: PandaIds) -> np.ndarray:
    """Per arm joint, the lag time (s) of a position servo against joint damping: ``damping / kp``."""
    kp = model.actuator_gainprm[ids.arm_actuators, 0]
    return model.dof_damping[ids.arm_dof] / np.maximum(kp, 1e-9)


def grasp_and_lift(
    model: mujoco.MjModel,
    data: mujoco.MjData,
    ids: PandaIds,
    grasp_pose_world: Pose,
    object_body: int | str,
    lift: float = 0.15,
    *,
    pregrasp: float = 0.10,
    hold: float = 1.0,
    success_height: float = 0.10,
    speed: float = 0.25,
    approach_speed: float = 0.08,
    joint_speed: float = 1.0,
    close_time: float = 0.6,
    allow_flip: bool = True,
    callback: Callable[[mujoco.MjModel, mujoco.MjData], None] | None = None,
) -> GraspResult:
    """Scripted grasp: pre-grasp -> approach -> close -> lift -> hold, then check the object is held.

    The grasp pose follows the gripper convention of this module: origin at the TCP (centre between the
    distal finger pads), z = approach direction (palm toward object), y = finger closing axis,
    x = y cross z. The pre-grasp pose is ``pregrasp`` metres back along -z from the grasp pose and is
    reached by a joint-space motion with the gripper open; the approach is a straight line; the lift
    moves the TCP straight up (world +z) by ``lift`` metres keeping the orientation.

    Args:
        model, data, ids: Model, state (advanced in place) and the Panda's ids.
        grasp_pose_world: ``T_world_grasp`` (m).
        object_body: Body id or name of the object to lift.
        lift: Lift height, m.
        pregrasp: Stand-off distance along the approach axis, m.
        hold: Hold time at the top, s.
        success_height: Minimum rise of the object (its body origin) after the hold, m.
        speed: Nominal TCP speed of the free motion to the pre-grasp pose, m/s.
        approach_speed: Mean TCP speed of the straight approach and of the lift, m/s (slow, so the
            TCP stays within about 2 mm of the straight line).
        joint_speed: Largest joint speed of the free motion to the pre-grasp pose, rad/s.
        close_time: Time given to the gripper to close, s.
        allow_flip: Execute whichever of the grasp and its :func:`symmetric_grasp` twin is closer to the
            current arm configuration (the gripper is symmetric under a half turn about z).
        callback: Called as ``callback(model, data)`` after every control period (e.g. to record frames).

    Returns:
        A :class:`GraspResult` (truthy on success).
    """
    if isinstance(object_body, str):
        name = object_body
        object_body = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, name)
        if object_body < 0:
            raise ConfigError(f"model has no body named {name!r}")
    if not 0 < object_body < model.nbody:
        raise ConfigError(f"object_body must be a body id in [1, {model.nbody - 1}], got {object_body!r}")
    t0 = data.time
    mujoco.mj_forward(model, data)
    rest_z = float(data.xpos[object_body][2])
    if allow_flip:
        grasp_pose_world = _choose_grasp(model, data, ids, grasp_pose_world, pregrasp)
    approach = grasp_pose_world.R[:, 2]
    pre = Pose(grasp_pose_world.R, grasp_pose_world.t - pregrasp * approach)
    lifted = Pose(grasp_pose_world.R, grasp_pose_world.t + np.array([0.0, 0.0, lift]))

    def _result(success: bool, reason: str) -> GraspResult:
        mujoco.mj_forward(model, data)
        return GraspResult(success, reason, float(data.xpos[object_body][2] - rest_z),
                           gripper_width(data, ids), float(data.time - t0))

    def _duration(a: Pose, b: Pose) -> float:
        return max(0.5, float(np.linalg.norm(b.t - a.t)) / speed)

    kw = dict(callback=callback)
    try:
        q_now = ids.arm_q(data)
        pre_ik = solve_ik(model, data, ids, pre, q_now)
        if not pre_ik.success:
            return _result(False, "unreachable")
        free_time = max(_duration(tcp_pose(data, ids), pre),
                        float(np.abs(pre_ik.q - q_now).max()) / joint_speed)
        q = move_to(model, data, ids, pre, free_time, path="joint", gripper=GRIPPER_OPEN, q_ref=q_now, **kw)
        for pose in (grasp_pose_world, lifted):  # reachability of the rest, before touching anything
            if not solve_ik(model, data, ids, pose, q).success:
                return _result(False, "unreachable")
        q = move_to(model, data, ids, grasp_pose_world, max(1.0, pregrasp / approach_speed), q_ref=q, **kw)
        close_gripper(data, ids)
        for _ in range(int(round(close_time / 0.05))):
            step_for(model, data, 0.05)
            if callback is not None:
                callback(model, data)
        q = move_to(model, data, ids, lifted, max(1.0, lift / approach_speed), settle=0.0, q_ref=q, **kw)
        for _ in range(int(round(hold / 0.05))):
            step_for(model, data, 0.05)
            if callback is not None:
                callback(model, data)
    except UnreachableError:
        return _result(False, "unreachable")
    mujoco.mj_forward(model, data)
    rise = float(data.xpos[object_body][2] - rest_z)
    if rise >= success_height:
        return _result(True, "ok")
    if gripper_width(data, ids) < 0.002:
        return _result(False, "empty")
    return _result(False, "dropped")


def symmetric_grasp(grasp_pose_world: Pose) -> Pose:
    """The same grasp with the fingers swapped: rotated by pi about the approach axis z.

    The Panda gripper is symmetric under this rotation, so both poses hold the object identically.
    """
    return grasp_pose_world @ Pose(np.diag([-1.0, -1.0, 1.0]), np.zeros(3))


def _choose_grasp(model: mujoco.MjModel, data: mujoco.MjData, ids: PandaIds, grasp: Pose,
                  pregrasp: float) -> Pose:
    """Of ``grasp`` and its symmetric twin, the one whose pre-grasp needs the smallest joint motion."""
    q_now = ids.arm_q(data)
    best, best_cost = grasp, np.inf
    for cand in (grasp, symmetric_grasp(grasp)):
        pre = Pose(cand.R, cand.t - pregrasp * cand.R[:, 2])
        res = solve_ik(model, data, ids, pre, q_now)
        if res.success:
            cost = float(np.abs(res.q - q_now).max())
            if cost < best_cost:
                best, best_cost = cand, cost
    return best


# --- wrist-camera viewpoints -------------------------------------------------------------------------------

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
    scratch = _scratch(model, data)
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
        if check_collisions and _in_collision(model, data, ids, res.q):
            continue
        views.append(res.q)
    if len(views) < n and not allow_fewer:
        raise ConfigError(
            f"found {len(views)} of {n} reachable wrist views of point {np.round(point, 3).tolist()} m in "
            f"{attempts} attempts (distance {distance_range} m, elevation {np.round(elevation_range, 3)} rad)"
            "; move the point closer to the robot, widen the ranges or pass allow_fewer=True")
    return views


# --- measurement --------------------------------------------------------------------------------------------

def _benchmark_scene() -> tuple[mujoco.MjModel, mujoco.MjData, PandaIds]:
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


if __name__ == "__main__":
    for key, value in benchmark().items():
        print(f"{key}: {value:.4g}")
