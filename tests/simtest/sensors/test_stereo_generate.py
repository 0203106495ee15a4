"""`generate` with a depth sensor: depth/ holds the sensed depth, depth_exact/ the exact one (the same files as
a run without the sensor), and every label stays exact."""

from __future__ import annotations

import cv2
import numpy as np

from simtest.io.bop import read_depth, scene_dirs


def _files(root, sub):
    return {p.relative_to(root).as_posix(): p.read_bytes() for p in sorted(root.rglob(sub)) if p.is_file()}


def test_generate_with_stereo_depth(small_config, small_dataset, tmp_path):
    from simtest.generators.pipeline import generate

    cfg = small_config.replace(**{"scenes": 1, "render.depth_sensor": "d435-stereo"})
    out = tmp_path / "stereo"
    generate(cfg, out, progress=False)
    again = tmp_path / "again"
    generate(cfg, again, progress=False)
    scene = scene_dirs(out / "train_pbr")[0]
    ref = scene_dirs(small_dataset / "train_pbr")[0]
    # labels and RGB as without the sensor; the exact depth moved to depth_exact/, same encoding
    for name in ("scene_gt.json", "scene_gt_info.json", "scene_camera.json"):
        assert (scene / name).read_bytes() == (ref / name).read_bytes(), name
    for sub in ("rgb", "mask", "mask_visib"):
        assert _files(scene / sub, "*") == _files(ref / sub, "*"), sub
    assert sorted(_files(scene / "depth_exact", "*")) == sorted(_files(ref / "depth", "*"))
    assert _files(scene / "depth", "*") != _files(ref / "depth", "*")
    assert _files(out, "*.png") == _files(again, "*.png")  # same seed, same bytes
    for im_id in range(3):
        exact = read_depth(ref, im_id, 0.1)
        raw_exact = cv2.imread(str(scene / "depth_exact" / f"{im_id:06d}.png"), cv2.IMREAD_UNCHANGED)
        raw_ref = cv2.imread(str(ref / "depth" / f"{im_id:06d}.png"), cv2.IMREAD_UNCHANGED)
        assert raw_exact.dtype == np.uint16 and np.array_equal(raw_exact, raw_ref)  # the same values, uint16
        sensed = read_depth(scene, im_id, 0.1)
        both = (exact > 0) & (sensed > 0)
        assert both.mean() > 0.3
        # 160 px wide: f_ir = 104 px, 1-2 m away a disparity of 2.5-5 px, so a few per cent of the range
        assert np.median(np.abs(sensed[both] - exact[both]) / exact[both]) < 0.05
