"""The Panda model, its IK, scripted grasps and the wrist camera, with real MuJoCo physics."""

from __future__ import annotations

import numpy as np
import pytest

import simtest  # noqa: F401  (selects the GL backend before mujoco is imported)
import mujoco

from simtest.camera import CameraModel
from simtest.errors import ConfigError
from simtest.geometry import Pose, rotation_about
from simtest import robot
from simtest.robot import (
    GRIPPER_OPEN,
    HOME_QPOS,
    T_TCP_CAM,
    UnreachableError,
    attach_panda,
    grasp_and_lift,
    gripper_width,
    ik_step,
    is_reachable,
    move_to,
    reset_arm,
    sample_wrist_views,
    solve_ik,
    step_for,
    tcp_pose,
    wrist_camera_model,
)

#: Top-down grasp orientation: approach z = world -z, closing axis y = world -y, x = world +x.
R_TOP_DOWN = np.diag([1.0, -1.0, -1.0])


def make_scene(shape: str = "box", mass: float = 0.1, base_pose: Pose = Pose.identity(),
               wrist_camera: CameraModel | None = CameraModel.default(64, 48)):
    """A table (top at z = 0) with one free object 0.5 m in front of the robot base."""
    spec = mujoco.MjSpec()
    spec.worldbody.add_light(pos=[0.5, 0.0, 2.0], dir=[0.0, 0.0, -1.0])
    spec.worldbody.add_geom(name="table", type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.4, 0.6, 0.02],
                            pos=[0.55, 0.0, -0.02], rgba=[0.6, 0.6, 0.6, 1.0])
    half_height = 0.025 if shape == "box" else 0.05
    body = spec.worldbody.add_body(name="obj", pos=[0.5, 0.0, half_height])
    body.add_freejoint()
    if shape == "box":  # 5 cm cube
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_BOX, size=[0.025] * 3, mass=mass, rgba=[1, 0, 0, 1])
    else:  # can: radius 3.3 cm, height 10 cm
        body.add_geom(type=mujoco.mjtGeom.mjGEOM_CYLINDER, size=[0.033, 0.05, 0.0], mass=mass,
                      rgba=[1, 0, 0, 1])
    handles = attach_panda(spec, base_pose=base_pose, wrist_camera=wrist_camera)
    model = spec.compile()
    data = mujoco.MjData(model)
    ids = handles.bind(model)
    reset_arm(model, data, ids)
    step_for(model, data, 0.2)  # let the object rest
    return model, data, ids


def rot_angle(Ra: np.ndarray, Rb: np.ndarray) -> float:
    return float(np.arccos(np.clip((np.trace(Ra.T @ Rb) - 1.0) / 2.0, -1.0, 1.0)))


@pytest.fixture(scope="module")
def box_scene():
    return make_scene("box")


# --- loading and attaching ---------------------------------------------------------------------------

def test_asset_dir_comes_from_the_wheel():
    folder = robot.panda_asset_dir()
    assert "gymnasium_robotics" in str(folder)
    assert (folder / "chain.xml").exists()


def test_attach_into_fresh_spec(box_scene):
    model, data, ids = box_scene
    assert model.nu == 8  # 7 arm position actuators + 1 gripper
    assert len(ids.arm_qpos) == 7 and len(ids.finger_qpos) == 2
    assert ids.camera >= 0 and ids.tcp_site >= 0 and len(ids.finger_geoms) > 0
    assert model.opt.timestep == pytest.approx(0.002)
    np.testing.assert_allclose(ids.arm_limits, robot.ARM_JOINT_LIMITS)
    assert np.all(HOME_QPOS > ids.arm_limits[:, 0]) and np.all(HOME_QPOS < ids.arm_limits[:, 1])
    # The wrist camera carries the requested intrinsics.
    assert model.cam_resolution[ids.camera].tolist() == [64, 48]
    # The object rests on the table; the arm holds HOME with the TCP pointing down 0.45 m ahead, 0.40 m up.
    obj = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "obj")
    assert data.xpos[obj][2] == pytest.approx(0.025, abs=2e-3)
    T = tcp_pose(data, ids)
    np.testing.assert_allclose(T.t, [0.45, 0.0, 0.40], atol=3e-3)
    assert rot_angle(T.R, R_TOP_DOWN) < np.deg2rad(1.0)
    assert gripper_width(data, ids) == pytest.approx(GRIPPER_OPEN, abs=1e-3)
    # The TCP sits between the pads, TCP_TO_FINGERTIP behind the fingertips.
    T_tcp_world = T.inverse()
    pads = T_tcp_world.apply(data.geom_xpos[ids.finger_geoms])
    assert np.abs(pads[:, 0]).max() < 1e-6
    tips = pads[:, 2] + model.geom_size[ids.finger_geoms, 0]  # capsule radius beyond the centre line
    assert tips.max() == pytest.approx(robot.TCP_TO_FINGERTIP, abs=1.5e-3)


def test_attach_honours_base_pose_and_rejects_reused_prefix():
    base = Pose(rotation_about([0, 0, 1], np.pi / 2), [0.3, -0.2, 0.1])
    model, data, ids = make_scene("box", base_pose=base, wrist_camera=None)
    assert ids.camera == -1
    reset_arm(model, data, ids)
    expected = base @ Pose(R_TOP_DOWN, [0.45, 0.0, 0.40])
    T = tcp_pose(data, ids)
    np.testing.assert_allclose(T.t, expected.t, atol=3e-3)
    spec = mujoco.MjSpec()
    attach_panda(spec, wrist_camera=None)
    with pytest.raises(ConfigError, match="prefix"):
        attach_panda(spec, wrist_camera=None)
    with pytest.raises(ConfigError):
        wrist_camera_model(data, ids)


def test_gripper_opens_and_closes_on_nothing(box_scene):
    model, _, ids = box_scene
    data = mujoco.MjData(model)
    reset_arm(model, data, ids, gripper=GRIPPER_OPEN)
    robot.close_gripper(data, ids)
    step_for(model, data, 0.6)
    assert gripper_width(data, ids) < 1e-3
    robot.open_gripper(data, ids)
    step_for(model, data, 0.6)
    assert gripper_width(data, ids) == pytest.approx(GRIPPER_OPEN, abs=1e-3)
    # The arm holds its posture under gravity (gravity compensation + position servos).
    assert np.abs(ids.arm_q(data) - HOME_QPOS).max() < 2e-3


# --- inverse kinematics ------------------------------------------------------------------------------

def test_ik_reaches_random_reachable_targets_within_limits(box_scene):
    model, data, ids = box_scene
    rng = np.random.default_rng(7)
    lo, hi = ids.arm_limits[:, 0], ids.arm_limits[:, 1]
    scratch = mujoco.MjData(model)
    qpos_before = data.qpos.copy()
    n_ok = 0
    for _ in range(20):
        q_true = rng.uniform(lo + 0.2 * (hi - lo), hi - 0.2 * (hi - lo))
        scratch.qpos[ids.arm_qpos] = q_true
        mujoco.mj_kinematics(model, scratch)
        target = tcp_pose(scratch, ids)
        res = solve_ik(model, data, ids, target, HOME_QPOS, rng=rng)
        assert np.all(res.q >= lo - 1e-12) and np.all(res.q <= hi + 1e-12)
        if res.success:
            n_ok += 1
            scratch.qpos[ids.arm_qpos] = res.q
            mujoco.mj_kinematics(model, scratch)
            got = tcp_pose(scratch, ids)
            assert np.linalg.norm(got.t - target.t) < 2e-3
            assert rot_angle(got.R, target.R) < np.deg2rad(1.0)
    assert n_ok >= 19  # every target is reachable by construction; allow one unlucky restart set
    np.testing.assert_array_equal(data.qpos, qpos_before)  # the caller's data is untouched


def test_ik_reports_unreachable_targets(box_scene):
    model, data, ids = box_scene
    far = Pose(R_TOP_DOWN, [2.0, 0.0, 0.3])
    res = solve_ik(model, data, ids, far)
    assert not res.success and res.pos_err > 0.5
    assert not is_reachable(model, data, ids, far)
    assert is_reachable(model, data, ids, Pose(R_TOP_DOWN, [0.5, 0.1, 0.2]))
    with pytest.raises(UnreachableError, match="mm"):
        move_to(model, mujoco.MjData(model), ids, far, 1.0)


def test_ik_step_moves_smoothly_to_target(box_scene):
    model, data, ids = box_scene
    target = Pose(R_TOP_DOWN @ rotation_about([0, 0, 1], 0.3), [0.55, 0.1, 0.30])
    q = HOME_QPOS.copy()
    scratch = mujoco.MjData(model)
    prev = Pose(R_TOP_DOWN, [0.45, 0.0, 0.40])
    for _ in range(40):  # 2 s at 20 Hz, 0.3 m/s limit
        q = ik_step(model, data, ids, target, 0.05, q_ref=q, max_lin_speed=0.3)
        scratch.qpos[ids.arm_qpos] = q
        mujoco.mj_kinematics(model, scratch)
        cur = tcp_pose(scratch, ids)
        assert np.linalg.norm(cur.t - prev.t) <= 0.3 * 0.05 + 1e-3
        prev = cur
    assert np.linalg.norm(prev.t - target.t) < 1e-3
    assert rot_angle(prev.R, target.R) < np.deg2rad(0.5)


# --- scripted grasps -----------------------------------------------------------------------------------

@pytest.mark.parametrize("shape", ["box", "can"])
def test_top_down_grasp_lifts_and_holds(shape):
    model, data, ids = make_scene(shape, mass=0.1)
    obj = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "obj")
    grasp = Pose(R_TOP_DOWN, data.xpos[obj].copy())
    result = grasp_and_lift(model, data, ids, grasp, obj, lift=0.15)
    assert result.success, result
    assert result.object_rise >= 0.10
    width = 0.05 if shape == "box" else 0.066
    assert result.gripper_width == pytest.approx(width, abs=3e-3)  # holding the object, not empty
    assert result.sim_time > 1.0  # includes the 1 s hold


def test_side_grasp_of_can_and_diagonal_grasp_of_box():
    # Horizontal approach along world +x, closing axis world -y (x = y cross z = world +z).
    side = np.column_stack([[0.0, 0.0, 1.0], [0.0, -1.0, 0.0], [1.0, 0.0, 0.0]])
    for shape, R in (("can", side), ("box", R_TOP_DOWN @ rotation_about([0, 0, 1], np.pi / 4))):
        model, data, ids = make_scene(shape)
        obj = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "obj")
        result = grasp_and_lift(model, data, ids, Pose(R, data.xpos[obj].copy()), obj)
        assert result.success, (shape, result)


def test_offset_grasp_beside_the_object_does_not_lift():
    model, data, ids = make_scene("box")
    obj = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "obj")
    grasp = Pose(R_TOP_DOWN, data.xpos[obj] + np.array([0.0, 0.10, 0.0]))
    result = grasp_and_lift(model, data, ids, grasp, obj)
    assert not result.success
    assert result.reason == "empty"
    assert abs(result.object_rise) < 0.01


# --- wrist camera ---------------------------------------------------------------------------------------

def test_wrist_camera_frame_matches_tcp_geometry(box_scene):
    model, _, ids = box_scene
    data = mujoco.MjData(model)
    reset_arm(model, data, ids, HOME_QPOS + np.array([0.3, 0.2, -0.2, 0.3, 0.4, -0.3, 0.5]))
    K = ids.wrist_camera.K
    cam = CameraModel.from_mujoco(data.cam_xpos[ids.camera], data.cam_xmat[ids.camera], K, 64, 48)
    T_world_tcp = tcp_pose(data, ids)
    expected = T_world_tcp @ T_TCP_CAM
    np.testing.assert_allclose(cam.T_world_cam.t, expected.t, atol=1e-6)
    np.testing.assert_allclose(cam.T_world_cam.R, expected.R, atol=1e-6)
    # Optical axis parallel to the approach axis; image x along the closing axis.
    assert cam.T_world_cam.R[:, 2] @ T_world_tcp.R[:, 2] > 0.9999
    assert abs(cam.T_world_cam.R[:, 0] @ T_world_tcp.R[:, 1]) > 0.9999


def test_wrist_camera_keeps_its_pose_when_the_arm_moves_on(box_scene):
    """A camera (and any Pose) made from MuJoCo's live arrays owns its values: the arm moving afterwards
    (the next view of a wrist rig, the next env step) does not move a camera already handed out."""
    model, _, ids = box_scene
    data = mujoco.MjData(model)
    reset_arm(model, data, ids)
    cam = wrist_camera_model(data, ids)
    before = cam.T_world_cam.t.copy(), cam.T_world_cam.R.copy()
    reset_arm(model, data, ids, HOME_QPOS + np.array([0.3, 0.2, -0.2, 0.3, 0.4, -0.3, 0.5]))
    assert np.linalg.norm(data.cam_xpos[ids.camera] - before[0]) > 0.01  # the live array did move
    np.testing.assert_array_equal(cam.T_world_cam.t, before[0])
    np.testing.assert_array_equal(cam.T_world_cam.R, before[1])
    assert data.cam_xpos.flags.writeable  # and the live array was left writeable


def test_wrist_camera_render_sees_the_object_where_projected(box_scene):
    model, _, ids = box_scene
    data = mujoco.MjData(model)
    reset_arm(model, data, ids)
    step_for(model, data, 0.1)
    cam = wrist_camera_model(data, ids)
    obj = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_BODY, "obj")
    (u, v), = cam.project_world(data.xpos[obj][None])[0]
    renderer = mujoco.Renderer(model, 48, 64)  # rendering is required: no skip when GL is missing
    with renderer:
        renderer.update_scene(data, camera=ids.camera)
        rgb = renderer.render()
        renderer.enable_depth_rendering()
        renderer.update_scene(data, camera=ids.camera)
        depth = renderer.render()
    r, g, b = (rgb[..., i].astype(int) for i in range(3))
    red = (r > 100) & (r > 2 * g) & (r > 2 * b)
    assert red.sum() > 20
    rows, cols = np.nonzero(red)
    assert abs(cols.mean() - u) < 1.5 and abs(rows.mean() - v) < 1.5
    # Depth at the box centre: the box top is 0.05 m above the table, seen from above.
    top_z = cam.T_cam_world.apply(np.array([data.xpos[obj] + [0, 0, 0.025]]))[0, 2]
    assert depth[int(round(v)), int(round(u))] == pytest.approx(top_z, abs=3e-3)


def test_sample_wrist_views_look_at_the_point(box_scene):
    model, data, ids = box_scene
    point = np.array([0.5, 0.0, 0.025])
    views = sample_wrist_views(model, data, ids, point, np.random.default_rng(3), 4)
    assert len(views) == 4
    scratch = mujoco.MjData(model)
    scratch.qpos[:] = data.qpos
    for q in views:
        assert np.all(q >= ids.arm_limits[:, 0]) and np.all(q <= ids.arm_limits[:, 1])
        scratch.qpos[ids.arm_qpos] = q
        mujoco.mj_kinematics(model, scratch)
        mujoco.mj_camlight(model, scratch)
        cam = wrist_camera_model(scratch, ids)
        (u, v), = cam.project_world(point[None])[0]
        assert abs(u - cam.K[0, 2]) < 0.5 and abs(v - cam.K[1, 2]) < 0.5
        assert 0.25 - 1e-3 <= np.linalg.norm(cam.T_world_cam.t - point) <= 0.6 + 1e-3
    # Same generator seed, same views.
    again = sample_wrist_views(model, data, ids, point, np.random.default_rng(3), 4)
    np.testing.assert_allclose(np.array(again), np.array(views))
    with pytest.raises(ConfigError, match="distance_range"):
        sample_wrist_views(model, data, ids, point, np.random.default_rng(0), 1, distance_range=(0.5, 0.2))
