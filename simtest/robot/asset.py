"""The Panda model: read from the ``gymnasium-robotics`` wheel, adapted, attached into a caller's MjSpec.

The robot model (meshes, kinematic chain, joint limits, arm actuator gains) comes from the MJCF shipped
in the ``gymnasium-robotics`` wheel (``envs/assets/kitchen_franka/franka_assets``, Apache-2.0). It is read
into a :class:`mujoco.MjSpec`, adapted (see below) and attached into a caller's scene spec with
:func:`attach_panda`. The frames (TCP, wrist camera) are described in :mod:`simtest.robot`.

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
from pathlib import Path

import numpy as np

import simtest  # noqa: F401  (selects the GL backend before mujoco is imported)
import mujoco

from simtest.camera import CameraModel
from simtest.errors import AssetError, ConfigError
from simtest.geometry import Pose
from simtest.robot.ids import PandaHandles

__all__ = ["ARM_JOINT_LIMITS", "FINGER_CONDIM", "FINGER_FRICTION", "FINGER_SOLIMP", "FINGER_SOLREF",
           "GRIPPER_CLOSED", "GRIPPER_FORCE", "GRIPPER_KP", "GRIPPER_OPEN", "HOME_QPOS", "T_LINK7_TCP",
           "T_TCP_CAM", "TCP_TO_FINGERTIP", "attach_panda", "configure_physics", "panda_asset_dir"]

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
    """The adapted Panda spec (see the module docstring), ready to attach."""
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
    _adapt_finger_pads(spec)
    _add_coupled_gripper(spec)
    hand = spec.body(_SOURCE_HAND_BODY)
    _add_tcp_site(hand)
    if wrist_camera is not None:
        _add_wrist_camera(hand, wrist_camera)
    return spec


def _adapt_finger_pads(spec: mujoco.MjSpec) -> None:
    """Name the finger collision geoms (``left_pad0``, ...) and give them stiff, high-friction contacts."""
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


def _add_coupled_gripper(spec: mujoco.MjSpec) -> None:
    """One position actuator on a tendon measuring the pad gap (m); an equality keeps the fingers symmetric."""
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


def _add_tcp_site(hand: mujoco.MjsBody) -> None:
    """The ``tcp`` site on link 7 at :data:`T_LINK7_TCP`."""
    tcp = hand.add_site()
    tcp.name = "tcp"
    tcp.pos = T_LINK7_TCP.t.tolist()
    tcp.quat = T_LINK7_TCP.quat_wxyz().tolist()
    tcp.size = [0.005, 0.005, 0.005]
    tcp.group = 4
    tcp.rgba = [1.0, 0.2, 0.2, 1.0]


def _add_wrist_camera(hand: mujoco.MjsBody, wrist_camera: CameraModel) -> None:
    """The ``wrist_camera`` on link 7 at :data:`T_TCP_CAM` from the TCP, with a visual-only housing."""
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


