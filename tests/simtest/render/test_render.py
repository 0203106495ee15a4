"""simtest's Renderer gives exactly the arrays of mujoco.Renderer's separate RGB, depth and segmentation passes."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest

from simtest.errors import RenderError
from simtest.generators.builder import DRAWN_GROUPS
from simtest.generators.pipeline import prepare_scene
from simtest.generators.recorder import scene_cameras
from simtest.objects import load_object_set
from simtest.render.rasterizer import Renderer


def test_renderer_equals_mujoco_renderer(small_config):
    objects = load_object_set(small_config.objects)
    scene, _, _, _ = prepare_scene(small_config, objects, 0)
    cam = scene_cameras(small_config, scene)[0][0]
    scene.set_camera(cam)
    with Renderer(scene.model, cam.width, cam.height) as r:
        ours = r.render(scene.data, scene.camera_id)
        again = r.render(scene.data, scene.camera_id)
    ref = mujoco.Renderer(scene.model, cam.height, cam.width)
    opt = mujoco.MjvOption()
    opt.geomgroup[:] = 0
    for g in DRAWN_GROUPS:
        opt.geomgroup[g] = 1
    for flag in (mujoco.mjtRndFlag.mjRND_SHADOW, mujoco.mjtRndFlag.mjRND_REFLECTION, mujoco.mjtRndFlag.mjRND_SKYBOX):
        ref.scene.flags[flag] = False
    ref.update_scene(scene.data, camera=scene.camera_id, scene_option=opt)
    rgb = ref.render()
    ref.enable_depth_rendering()
    depth = ref.render()
    ref.disable_depth_rendering()
    ref.enable_segmentation_rendering()
    seg = ref.render()
    ref.close()
    assert np.array_equal(ours.rgb, rgb)
    assert np.array_equal(ours.depth, np.where(depth < r.zfar * 0.999, depth, 0))
    assert np.array_equal(ours.seg, np.where(seg[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM), seg[..., 0], -1))
    assert np.array_equal(ours.rgb, again.rgb) and np.array_equal(ours.seg, again.seg)
    assert (ours.seg >= 0).mean() > 0.5 and (ours.depth > 0).all()


def test_segmentation_of_a_scene_with_more_geoms_than_one_colour_channel_codes():
    """Above 254 drawn geoms the segmentation ids span two colour channels: still MuJoCo's own ids."""
    boxes = "".join(f'<geom type="box" size="0.011 0.011 0.01" pos="{0.025 * (i % 20) - 0.24:.3f} '
                    f'{0.025 * (i // 20) - 0.2:.3f} 0" rgba="0.5 0.5 0.5 1"/>' for i in range(320))
    model = mujoco.MjModel.from_xml_string(f"""<mujoco><worldbody><geom type="plane" size="1 1 0.1"/>{boxes}
        <camera name="top" pos="0 0 1.1" xyaxes="1 0 0 0 1 0" fovy="30"/></worldbody></mujoco>""")
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    with Renderer(model, 160, 120) as r:
        ours = r.render(data, "top", rgb=False)
    ref = mujoco.Renderer(model, 120, 160)
    ref.update_scene(data, camera="top")
    ref.enable_segmentation_rendering()
    seg = ref.render()
    ref.close()
    assert model.ngeom > 256
    assert np.array_equal(ours.seg, np.where(seg[..., 1] == int(mujoco.mjtObj.mjOBJ_GEOM), seg[..., 0], -1))
    assert ours.seg.max() > 255 and len(np.unique(ours.seg)) > 200


def test_renderer_errors_name_the_problem(small_config):
    objects = load_object_set(small_config.objects)
    scene, _, _, _ = prepare_scene(small_config, objects, 0)
    with pytest.raises(RenderError, match="exceeds the model's offscreen buffer"):
        Renderer(scene.model, 100000, 10)
    with Renderer(scene.model, 32, 24) as r:
        with pytest.raises(RenderError, match="unknown camera 'nope'"):
            r.render(scene.data, "nope")


def test_no_gl_backend_error_names_the_system_packages(monkeypatch, small_config):
    """When no OpenGL context can be made, the error says which packages to install (no silent crash)."""
    import simtest.render.rasterizer as render

    objects = load_object_set(small_config.objects)
    scene, _, _, _ = prepare_scene(small_config, objects, 0)

    def broken(*args, **kwargs):
        raise RuntimeError("eglInitialize failed")

    monkeypatch.setattr(render, "_CONTEXT", {})
    monkeypatch.setattr(render.mujoco, "GLContext", broken)
    with pytest.raises(RenderError, match=r"eglInitialize failed.*libegl1.*libosmesa6"):
        Renderer(scene.model, 32, 24)


def test_rgb_with_depth_in_one_pass_gives_the_segmentation_pass_depth(small_config):
    """RGB + depth without segmentation reads the colour pass's depth buffer: the same values, bit for bit, as
    the segmentation pass's depth (the exact depth of every ground-truth file)."""
    objects = load_object_set(small_config.objects)
    scene, *_ = prepare_scene(small_config, objects, 0)
    r = Renderer(scene.model, small_config.camera.width, small_config.camera.height)
    for cam, _ in scene_cameras(small_config, scene):
        scene.set_camera(cam)
        one = r.render(scene.data, scene.camera_id, rgb=True, depth=True, seg=False)
        two = r.render(scene.data, scene.camera_id, rgb=True, depth=True, seg=True)
        np.testing.assert_array_equal(one.depth, two.depth)
        np.testing.assert_array_equal(one.rgb, two.rgb)
        assert one.seg is None and (one.depth > 0).mean() > 0.5
    r.close()
