"""The renderer's fused segmentation+depth pass equals MuJoCo's separate passes exactly."""

from __future__ import annotations

import numpy as np

from simtest.generators.pipeline import prepare_scene, scene_cameras
from simtest.objects import load_object_set
from simtest.render import Renderer


def test_fused_seg_depth_pass_equals_separate_passes(small_config):
    objects = load_object_set(small_config.objects)
    scene, _, _, _ = prepare_scene(small_config, objects, 0)
    cam = scene_cameras(small_config, scene)[0][0]
    scene.set_camera(cam)
    with Renderer(scene.model, cam.width, cam.height) as r:
        assert r._fused
        fused = r.render(scene.data, scene.camera_id)
        depth_only = r.render(scene.data, scene.camera_id, rgb=False, seg=False)
        seg_only = r.render(scene.data, scene.camera_id, rgb=False, depth=False)
    assert np.array_equal(fused.seg, seg_only.seg)
    assert np.array_equal(fused.depth, depth_only.depth)
    assert (fused.seg >= 0).mean() > 0.5 and (fused.depth > 0).all()
