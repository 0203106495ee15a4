"""The drawing primitives of simtest.viz, checked numerically on a generated dataset: contours on the mask
boundary, box corners at K (R x + t), the colour channels' decoding."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from simtest.io import bop
from simtest.io.dataset import select_images
from simtest.objects.loaders import load_dataset_objects
from simtest.io.dense import decode_flow as decode_kitti_flow
from simtest.viz.channels import colourize_depth, colourize_flow
from simtest.viz.dataset_page import draw_instance_gt, gt_canvas
from simtest.viz.draw import box_corner_pixels, draw_box, draw_mask_contour, mesh_silhouette, palette, to_canvas


@pytest.fixture(scope="module")
def scene(small_dataset):
    objects = load_dataset_objects(small_dataset)
    refs = select_images(small_dataset, "train_pbr", None, None, objects.ids)
    return objects, refs


def _instances(refs):
    """(ref, gt_id, gt) of every instance with a visible mask of at least 20 pixels."""
    for ref in refs:
        for j, g in enumerate(ref.info["gt"]):
            if g.px_count_visib >= 20:
                yield ref, j, g


def _boundary(mask: np.ndarray) -> np.ndarray:
    """Mask pixels with a 4-neighbour outside the mask (or on the image border)."""
    m = np.pad(mask, 1)
    inner = m[1:-1, 1:-1] & m[:-2, 1:-1] & m[2:, 1:-1] & m[1:-1, :-2] & m[1:-1, 2:]
    return mask & ~inner


@pytest.mark.parametrize("scale", [1, 3])
def test_contour_pixels_lie_on_the_visible_mask_boundary(scene, scale):
    _, refs = scene
    checked = 0
    for ref, j, _ in _instances(refs):
        mask = bop.read_mask(ref.gt_dir, ref.im_id, j, visible=True)
        canvas = np.zeros((mask.shape[0] * scale, mask.shape[1] * scale, 3), np.uint8)
        draw_mask_contour(canvas, mask, (255, 0, 0), scale, thickness=2)
        v, u = np.nonzero(canvas[..., 0] == 255)
        assert len(v) > 0
        near = cv2.dilate(_boundary(mask).astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        # Every painted canvas pixel belongs to a camera pixel within 1 px of a boundary pixel of the mask.
        assert near[v // scale, u // scale].all(), (ref.scene_id, ref.im_id, j)
        # And the whole boundary is drawn.
        painted = np.zeros_like(mask)
        painted[v // scale, u // scale] = True
        assert painted[_boundary(mask)].mean() > 0.99
        checked += 1
    assert checked >= 4


def test_box_corner_pixels_are_K_R_x_plus_t(scene):
    objects, refs = scene
    for ref, _, g in _instances(refs):
        obj = objects.get(g.obj_id)
        K, R, t = ref.info["K"], g.T_cam_obj.R, g.T_cam_obj.t
        uv = box_corner_pixels(K, R, t, obj.keypoints_bbox)
        p = (K @ (R @ obj.keypoints_bbox.T + t[:, None])).T
        np.testing.assert_allclose(uv, p[:, :2] / p[:, 2:], atol=1e-9)
        cv_uv, _ = cv2.projectPoints(obj.keypoints_bbox, cv2.Rodrigues(R)[0], t, K, None)
        np.testing.assert_allclose(uv, cv_uv.reshape(-1, 2), atol=1e-6)
        # The corners are the model's bbox corners: bit b of the index picks the max along axis b.
        lo, hi = obj.bbox
        assert np.allclose(obj.keypoints_bbox[0], lo) and np.allclose(obj.keypoints_bbox[7], hi)


@pytest.mark.parametrize("scale", [1, 4])
def test_box_corners_are_coloured_in_the_drawing(scene, scale):
    objects, refs = scene
    seen = 0
    for ref, j, g in _instances(refs):
        obj = objects.get(g.obj_id)
        K, R, t = ref.info["K"], g.T_cam_obj.R, g.T_cam_obj.t
        h, w = 120 * scale, 160 * scale
        colour = palette(j)
        canvas = np.zeros((h, w, 3), np.uint8)
        draw_instance_gt(canvas, K, g, obj, colour, scale, None, None, None)
        pts = np.round(to_canvas(box_corner_pixels(K, R, t, obj.keypoints_bbox), scale)).astype(int)
        inside = [(u, v) for u, v in pts if 0 <= u < w and 0 <= v < h]
        for u, v in inside:
            assert tuple(canvas[v, u]) == colour, (ref.im_id, j, u, v, canvas[v, u])
        seen += len(inside)
        # The same corners carry the instance colour on the page picture (the RGB with every instance drawn).
        page, drawn = gt_canvas(ref, objects, scale, only=[j], labels=False)
        assert drawn == [j]
        for u, v in inside:
            assert tuple(page[v, u]) == colour
    assert seen >= 16


def test_draw_box_leaves_points_behind_the_camera_out():
    img = np.zeros((50, 50, 3), np.uint8)
    uv = np.array([[10.0, 10.0]] * 4 + [[np.nan, np.nan]] * 4)
    draw_box(img, uv, (255, 255, 255))
    assert img.any()


def test_mesh_silhouette_of_the_gt_pose_matches_the_amodal_mask(scene):
    objects, refs = scene
    for ref, j, g in list(_instances(refs))[:6]:
        obj = objects.get(g.obj_id)
        amodal = bop.read_mask(ref.gt_dir, ref.im_id, j, visible=False)
        sil = mesh_silhouette(ref.info["K"], g.T_cam_obj.R, g.T_cam_obj.t, obj.vertices, obj.faces, 160, 120)
        iou = (sil & amodal).sum() / max(1, (sil | amodal).sum())
        assert iou > 0.97, (ref.im_id, j, iou)


def test_depth_holes_are_black_and_flow_decodes():
    d = np.full((4, 5), 0.5, np.float32)
    d[1, 2] = 0.0
    pic = colourize_depth(d)
    assert tuple(pic.image[1, 2]) == (0, 0, 0) and pic.image[0, 0].any() and "holes" in pic.caption
    raw = np.zeros((2, 2, 3), np.uint16)
    raw[..., 0] = 2 ** 15 + 64 * 3  # u = +3 px
    raw[..., 1] = 2 ** 15 - 64 * 2  # v = -2 px
    raw[0, 0, 2] = 1
    flow, valid = decode_kitti_flow(raw)
    np.testing.assert_allclose(flow[0, 0], [3.0, -2.0])
    assert valid.tolist() == [[True, False], [False, False]]
    rgb = colourize_flow(flow, valid).image
    assert rgb[0, 0].any() and not rgb[1, 1].any()
