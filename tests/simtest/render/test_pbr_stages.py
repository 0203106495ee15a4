"""The path tracer's per-stage timers and its shared BSDFs (small real renders)."""

from __future__ import annotations

import importlib.util
import numpy as np
import pytest

import simtest  # noqa: F401
import mujoco

from simtest.camera import CameraModel, look_at_pose
from simtest.render.pbr_stages import STAGES, StageTimes, process_stages

if importlib.util.find_spec("mitsuba") is None or importlib.util.find_spec("pyoidn") is None:
    pytest.skip("the pbr extra is not installed", allow_module_level=True)

from simtest.render.pbr import PbrRenderer  # noqa: E402  (after the extra's check)

W, H = 64, 48


def _scene() -> tuple[mujoco.MjModel, mujoco.MjData, CameraModel]:
    """Two boxes and a plane with one textured material (a shared BSDF) and a light."""
    xml = f"""<mujoco><visual><headlight ambient="0.3 0.3 0.3" diffuse="0 0 0" specular="0 0 0"/></visual>
      <asset><texture name="chk" type="2d" builtin="checker" rgb1="0.9 0.9 0.9" rgb2="0.1 0.3 0.1" width="32"
                      height="32"/>
             <material name="m" texture="chk" texrepeat="3 3" shininess="0.3"/></asset>
      <worldbody><light pos="0 0 2" dir="0 0 -1" diffuse="0.8 0.8 0.8"/>
        <geom name="floor" type="plane" size="1 1 0.1" material="m"/>
        <geom name="a" type="box" size="0.03 0.03 0.03" pos="-0.06 0 0.03" material="m"/>
        <geom name="b" type="box" size="0.03 0.03 0.03" pos="0.06 0 0.03" material="m"/>
        <geom name="c" type="box" size="0.02 0.02 0.02" pos="0 0.07 0.02" rgba="0.9 0.1 0.1 1"/>
        <camera name="cam" pos="0 0 0.5"/>
      </worldbody></mujoco>"""
    model = mujoco.MjModel.from_xml_string(xml)
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    cam = CameraModel(np.array([[60.0, 0, (W - 1) / 2], [0, 60.0, (H - 1) / 2], [0, 0, 1]]), W, H,
                      look_at_pose([0.0, -0.2, 0.45], [0.0, 0.0, 0.0], up=[0.0, 0.0, 1.0]))
    _place(model, data, cam)
    return model, data, cam


def _place(model: mujoco.MjModel, data: mujoco.MjData, cam: CameraModel) -> None:
    cid = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_CAMERA, "cam")
    pos, R = cam.mujoco_pose()
    data.cam_xpos[cid], data.cam_xmat[cid] = pos, R.reshape(-1)


def test_every_stage_of_a_frame_is_timed_and_the_scene_loaded_once_per_state():
    """Two views of one state: every stage takes time, the scene is loaded once, the process-wide times grow by
    this renderer's; an unknown stage is refused with the list of stages."""
    model, data, cam = _scene()
    before = process_stages().copy()
    r = PbrRenderer(model, cam, spp=2)
    r.render(data, "cam", seed=1)
    _place(model, data, CameraModel(cam.K, W, H, look_at_pose([0.1, -0.2, 0.4], [0.0, 0.0, 0.0], up=[0, 0, 1])))
    r.render(data, "cam", seed=2)
    assert r.stages.frames == 2 and r.stages.loads == 1
    assert set(r.stages.seconds) == set(STAGES)
    assert all(s > 0 for s in r.stages.seconds.values()), r.stages.seconds
    added = process_stages().since(before)
    assert added.frames == 2 and added.loads == 1
    assert added.total == pytest.approx(r.stages.total, rel=1e-9)
    assert r.stages.per_frame()["trace"] == pytest.approx(r.stages.seconds["trace"] / 2)
    with pytest.raises(KeyError, match="stages: scene"):
        with StageTimes().stage("jpeg"):
            pass


class _OneBsdfPerGeom(PbrRenderer):
    """A PbrRenderer whose geoms each load their own BSDF (as before BSDFs were shared)."""

    def _shared_bsdf(self, g, rgba):
        return self._bsdf(g, rgba)


def test_geoms_of_one_material_share_a_bsdf_with_the_same_bytes_as_a_bsdf_each():
    """The floor and two boxes of one textured material share one loaded BSDF (the red box has its own); the
    image is byte for byte the one of a renderer that loads a BSDF per geom, and the same on a fresh renderer."""
    model, data, cam = _scene()
    shared = PbrRenderer(model, cam, spp=4)
    a = shared.render(data, "cam", seed=7).rgb
    assert len(shared._bsdfs) == 2
    b = _OneBsdfPerGeom(model, cam, spp=4).render(data, "cam", seed=7).rgb
    c = PbrRenderer(model, cam, spp=4).render(data, "cam", seed=7).rgb
    assert a.std() > 5  # a real picture: the checker and the boxes
    np.testing.assert_array_equal(a, b)
    np.testing.assert_array_equal(a, c)
