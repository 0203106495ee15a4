"""Ground truth must agree with the rendered pixels: poses, masks, depth and visibility, checked numerically."""

from __future__ import annotations

import json

import numpy as np
import pytest

from simtest.camera import CameraModel, intrinsics_matrix
from simtest.io.bop import read_depth, read_mask, read_scene, scene_dirs
from simtest.objects import load_object_set
from simtest.render.zbuffer import render_depth


def model_surface_depth(obj, gt, im, shape: tuple[int, ...]) -> np.ndarray:
    """(H, W) metres: the depth of ``obj``'s surface alone at its ground-truth pose ``gt`` in image ``im``
    (0 where it is not), rendered independently of the dataset's renderer."""
    return render_depth(obj.vertices, obj.faces, gt.T_cam_obj.R, gt.T_cam_obj.t, im["K"], shape[1], shape[0])


def bop_rule_mask(model_depth: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """The BOP toolkit's visibility rule on noise-free depth: the object's pixels not behind the scene's
    surface by more than 5 mm (or where the scene has no depth)."""
    return (model_depth > 0) & ((depth == 0) | (model_depth - depth <= 0.005))


def _instances(dataset):
    for scene_dir in scene_dirs(dataset / "train_pbr"):
        for im_id, im in read_scene(scene_dir).items():
            depth = read_depth(scene_dir, im_id, im["depth_scale"])
            for gt_id, gt in enumerate(im["gt"]):
                yield scene_dir, im_id, im, depth, gt_id, gt



@pytest.fixture(scope="module", params=["shell", "wrist"])
def rig_dataset(request, small_dataset, small_config, tmp_path_factory):
    """The small dataset (camera shell rig) and one made through the Panda's wrist camera, whose camera moves
    with the arm between views."""
    if request.param == "shell":
        return small_dataset
    from simtest.generators.pipeline import generate

    out = tmp_path_factory.mktemp("ds") / "wrist"
    generate(small_config.replace(rig="wrist"), out, progress=False)
    return out


def _segmentation(spec, cam: CameraModel) -> np.ndarray:
    """Geom-id segmentation of the MjSpec ``spec`` seen by ``cam`` (added as camera "c"), rendered by MuJoCo."""
    import mujoco

    from simtest.geometry import Pose
    from simtest.render.rasterizer import Renderer

    pos, R_mj = cam.mujoco_pose()
    c = spec.worldbody.add_camera(name="c", pos=pos.tolist(), **cam.mujoco_intrinsics())
    c.quat = Pose(R_mj, pos).quat_wxyz().tolist()
    model = spec.compile()
    data = mujoco.MjData(model)
    mujoco.mj_forward(model, data)
    with Renderer(model, cam.width, cam.height) as r:
        return r.render(data, "c", rgb=False, depth=False).seg

def test_dataset_layout_and_json_fields(small_dataset, small_config):
    cam = json.loads((small_dataset / "camera.json").read_text())
    assert set(cam) == {"cx", "cy", "depth_scale", "fx", "fy", "height", "width"}
    assert cam["width"] == 160 and cam["depth_scale"] == 0.1
    info = json.loads((small_dataset / "models" / "models_info.json").read_text())
    assert info and all({"diameter", "min_x", "size_x"} <= set(v) for v in info.values())
    manifest = json.loads((small_dataset / "manifest.json").read_text())
    assert manifest["seed"] == 7 and manifest["config"]["scenes"] == 2 and "mujoco" in manifest["versions"]
    scenes = scene_dirs(small_dataset / "train_pbr")
    assert [p.name for p in scenes] == ["000000", "000001"]
    for scene_dir in scenes:
        sc = json.loads((scene_dir / "scene_camera.json").read_text())
        gt = json.loads((scene_dir / "scene_gt.json").read_text())
        gi = json.loads((scene_dir / "scene_gt_info.json").read_text())
        assert list(sc) == list(gt) == list(gi) == ["0", "1", "2"]
        for k in sc:
            assert len(sc[k]["cam_K"]) == 9 and len(sc[k]["cam_R_w2c"]) == 9 and len(sc[k]["cam_t_w2c"]) == 3
            assert len(gt[k]) == len(gi[k]) >= 1
            for g, i in zip(gt[k], gi[k]):
                assert set(g) == {"cam_R_m2c", "cam_t_m2c", "obj_id"}
                assert set(i) == {"bbox_obj", "bbox_visib", "px_count_all", "px_count_valid", "px_count_visib",
                                  "visib_fract"}
                # Translations are millimetres: objects sit 0.2-3 m from the camera.
                assert 200 < np.linalg.norm(g["cam_t_m2c"]) < 3000
            # BOP's PBR layout: JPEG colour, 16-bit PNG depth
            assert (scene_dir / "rgb" / f"{int(k):06d}.jpg").is_file()
            assert (scene_dir / "depth" / f"{int(k):06d}.png").is_file()


def _calc_2d_bbox(mask: np.ndarray) -> list[int]:
    """The BOP toolkit's ``misc.calc_2d_bbox`` of a mask's pixels: ``[xmin, ymin, xmax - xmin, ymax - ymin]``."""
    ys, xs = np.nonzero(mask)
    return [int(xs.min()), int(ys.min()), int(xs.max() - xs.min()), int(ys.max() - ys.min())]


def test_mask_bbox_is_the_toolkits_box():
    from simtest.io.bop import mask_bbox

    m = np.zeros((6, 8), bool)
    m[2, 3] = True
    assert mask_bbox(m) == [3, 2, 0, 0]  # one pixel: zero width and height, as calc_2d_bbox
    m[4, 6] = True
    assert mask_bbox(m) == [3, 2, 3, 2] == _calc_2d_bbox(m)
    assert mask_bbox(m, x0=-5, y0=10) == [-2, 12, 3, 2]
    assert mask_bbox(np.zeros((3, 3), bool)) == [-1, -1, -1, -1]


def test_boxes_match_bop_toolkit_calc_2d_bbox(small_dataset):
    """bbox_visib is calc_2d_bbox of mask_visib; bbox_obj is that of the amodal mask (for untruncated objects)
    and contains the in-image amodal mask otherwise."""
    checked_obj = 0
    for scene_dir, im_id, im, depth, gt_id, gt in _instances(small_dataset):
        visib = read_mask(scene_dir, im_id, gt_id, visible=True)
        amodal = read_mask(scene_dir, im_id, gt_id, visible=False)
        assert gt.bbox_visib == (_calc_2d_bbox(visib) if visib.any() else [-1, -1, -1, -1])
        if not amodal.any():
            continue
        x, y, w, h = gt.bbox_obj
        if gt.px_count_all == amodal.sum():  # the whole silhouette is in the image
            assert gt.bbox_obj == _calc_2d_bbox(amodal)
            checked_obj += 1
        else:
            ax, ay, aw, ah = _calc_2d_bbox(amodal)
            assert x <= ax and y <= ay and x + w >= ax + aw and y + h >= ay + ah
    assert checked_obj >= 5


def test_pixel_centres_follow_opencv_and_vispy_needs_half_pixel_shift():
    """A rendered sphere covers the pixels whose centre (u, v) its outline contains, with K as given (OpenCV,
    centres at integers). A renderer sampling at (u + 0.5, v + 0.5), as the BOP toolkit's vispy renderer,
    gives the same pixels with cx + 0.5, cy + 0.5 and pixels shifted by half a pixel without."""
    import mujoco

    from simtest.geometry import Pose

    W, H = 120, 90
    K = intrinsics_matrix(150.0, 150.0, (W - 1) / 2, (H - 1) / 2)
    cam = CameraModel(K, W, H, Pose(np.eye(3), np.zeros(3)))
    centre, radius = np.array([0.013, -0.021, 0.5]), 0.06
    spec = mujoco.MjSpec()
    spec.visual.global_.offwidth, spec.visual.global_.offheight = W, H
    spec.worldbody.add_geom(type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[radius, 0, 0], pos=centre.tolist())
    seg = _segmentation(spec, cam) >= 0

    def covered(K_: np.ndarray, offset: float) -> np.ndarray:
        """Pixels whose sample point (u + offset, v + offset) sees the sphere (ray-sphere test)."""
        v, u = np.mgrid[0:H, 0:W].astype(np.float64)
        rays = np.stack([u + offset, v + offset, np.ones_like(u)], -1) @ np.linalg.inv(K_).T
        rays /= np.linalg.norm(rays, axis=-1, keepdims=True)
        along = rays @ centre
        return (centre @ centre - along ** 2) < radius ** 2

    opencv = covered(K, 0.0)
    K_vispy = K.copy()
    K_vispy[0, 2] += 0.5
    K_vispy[1, 2] += 0.5
    assert np.array_equal(covered(K_vispy, 0.5), opencv)
    unshifted = covered(K, 0.5)

    def centroid(m: np.ndarray) -> np.ndarray:
        ys, xs = np.nonzero(m)
        return np.array([xs.mean(), ys.mean()])

    assert np.abs(centroid(seg) - centroid(opencv)).max() < 0.15
    assert np.abs(centroid(seg) - centroid(unshifted)).min() > 0.35
    assert (seg & opencv).sum() / (seg | opencv).sum() > 0.95


def test_reprojected_vertices_land_on_masks(rig_dataset):
    """Model vertices through the GT pose and K: inside the amodal mask; visible ones inside the visible mask."""
    objects = load_object_set("builtin-small")
    checked = 0
    for scene_dir, im_id, im, depth, gt_id, gt in _instances(rig_dataset):
        if gt.px_count_visib < 30:
            continue
        cam = CameraModel(im["K"], depth.shape[1], depth.shape[0])
        obj = objects.get(gt.obj_id)
        v = gt.T_cam_obj.apply(obj.vertices)
        uv, z = cam.project(v)
        px = np.round(uv).astype(int)
        inside = (px[:, 0] >= 0) & (px[:, 0] < cam.width) & (px[:, 1] >= 0) & (px[:, 1] < cam.height)
        amodal = read_mask(scene_dir, im_id, gt_id, visible=False)
        visib = read_mask(scene_dir, im_id, gt_id, visible=True)
        # A vertex projects onto a silhouette pixel or an 8-neighbour of one (vertices on the outline); only
        # sub-pixel slivers (a banana's tip) may cover no pixel centre at all.
        import cv2

        grown = cv2.dilate(amodal.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
        assert grown[px[inside, 1], px[inside, 0]].mean() > 0.99
        # Vertices whose depth matches the rendered depth are visible: they must fall on the visible mask.
        d = depth[px[inside, 1], px[inside, 0]]
        seen = np.abs(d - z[inside]) < 0.002
        if seen.sum() >= 5:
            grown_v = cv2.dilate(visib.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
            assert grown_v[px[inside][seen, 1], px[inside][seen, 0]].mean() > 0.97
            checked += 1
    assert checked >= 5


def test_depth_equals_model_surface_depth(rig_dataset):
    """Rendered depth equals the model surface depth at the GT pose (median |diff| < 1 mm on visible pixels)."""
    objects = load_object_set("builtin-small")
    diffs = []
    for scene_dir, im_id, im, depth, gt_id, gt in _instances(rig_dataset):
        if gt.px_count_visib < 30:
            continue
        model_depth = model_surface_depth(objects.get(gt.obj_id), gt, im, depth.shape)
        visib = read_mask(scene_dir, im_id, gt_id)
        sel = visib & (model_depth > 0) & (depth > 0)
        d = np.abs(depth[sel] - model_depth[sel])
        assert np.median(d) < 0.001, f"scene {scene_dir.name} im {im_id} obj {gt.obj_id}: {np.median(d)}"
        diffs.append(d)
    assert len(diffs) >= 5
    assert np.median(np.concatenate(diffs)) < 0.0005


def test_visib_fract_counts_and_bop_visibility_rule(small_dataset):
    """visib_fract matches the mask pixel counts, and the BOP rule on noise-free depth gives the same mask."""
    objects = load_object_set("builtin-small")
    for scene_dir, im_id, im, depth, gt_id, gt in _instances(small_dataset):
        amodal = read_mask(scene_dir, im_id, gt_id, visible=False)
        visib = read_mask(scene_dir, im_id, gt_id, visible=True)
        assert visib.sum() == gt.px_count_visib
        assert not (visib & ~amodal).any(), "visible pixels outside the amodal mask"
        assert gt.px_count_all >= amodal.sum()  # out-of-frame pixels count too
        if gt.px_count_all:
            assert gt.visib_fract == pytest.approx(gt.px_count_visib / gt.px_count_all)
        if gt.px_count_visib < 30:
            continue
        model_depth = model_surface_depth(objects.get(gt.obj_id), gt, im, depth.shape)
        rule = bop_rule_mask(model_depth, depth)
        inter = (rule & visib).sum()
        union = (rule | visib).sum()
        assert inter / union > 0.9, f"BOP-rule mask disagrees: IoU {inter / union:.3f}"


def test_amodal_mask_equals_independent_silhouette(small_config):
    """Amodal masks vs a MuJoCo segmentation render of each object alone (others parked away): IoU >= 0.98."""
    from simtest.generators.annotate import annotate
    from simtest.generators.pipeline import prepare_scene
    from simtest.generators.recorder import scene_cameras
    from simtest.generators.settle import park
    from simtest.render.rasterizer import Renderer

    objects = load_object_set(small_config.objects)
    scene, _, _, _ = prepare_scene(small_config, objects, 0)
    cam = scene_cameras(small_config, scene)[0][0]
    scene.set_camera(cam)
    with Renderer(scene.model, cam.width, cam.height) as r:
        anns = annotate(scene, r.render(scene.data, scene.camera_id), cam, objects)
        active = [i for i, a in enumerate(scene.active) if a]
        assert len(anns) == len(active)
        qpos = scene.data.qpos.copy()
        ious = []
        for ann, i in zip(anns, active):
            for j in active:
                if j != i:
                    park(scene, j)
            # Distractors stay: park them too by moving every free body that is not instance i.
            import mujoco

            for b in range(scene.model.nbody):
                if scene.model.body_jntnum[b] and b not in scene.instance_bodies and \
                        scene.model.jnt_type[scene.model.body_jntadr[b]] == mujoco.mjtJoint.mjJNT_FREE:
                    adr = scene.model.jnt_qposadr[scene.model.body_jntadr[b]]
                    scene.data.qpos[adr:adr + 3] = [400.0, 400.0, -400.0]
            mujoco.mj_forward(scene.model, scene.data)
            scene.set_camera(cam)
            seg = r.render(scene.data, scene.camera_id, rgb=False, depth=False).seg
            alone = scene.geom_instance[np.clip(seg, 0, None)] == i
            alone &= seg >= 0
            scene.data.qpos[:] = qpos
            scene.active[:] = [True] * len(scene.active)
            mujoco.mj_forward(scene.model, scene.data)
            union = (alone | ann.mask).sum()
            if union == 0:
                continue
            ious.append((alone & ann.mask).sum() / union)
    assert ious and min(ious) >= 0.98, ious


@pytest.mark.parametrize("cx_off, cy_off, fy_scale", [(0.0, 0.0, 1.0), (17.3, -11.6, 1.15)])
def test_intrinsics_match_rendered_pixels(cx_off, cy_off, fy_scale):
    """A small sphere at known camera coordinates renders where K projects it (principal point signs)."""
    import mujoco

    from simtest.geometry import Pose

    W, H = 200, 150
    K = intrinsics_matrix(180.0, 180.0 * fy_scale, (W - 1) / 2 + cx_off, (H - 1) / 2 + cy_off)
    cam = CameraModel(K, W, H, Pose(np.eye(3), np.zeros(3)))
    spec = mujoco.MjSpec()
    spec.visual.global_.offwidth, spec.visual.global_.offheight = W, H
    points = np.array([[0.08, -0.05, 0.6], [-0.1, 0.07, 0.7], [0.0, 0.0, 0.5]])
    for k, p in enumerate(points):
        spec.worldbody.add_geom(name=f"s{k}", type=mujoco.mjtGeom.mjGEOM_SPHERE, size=[0.015, 0, 0], pos=p.tolist())
    seg = _segmentation(spec, cam)
    uv, _ = cam.project(points)
    for k in range(len(points)):
        ys, xs = np.nonzero(seg == k)
        assert len(xs) > 10
        assert abs(xs.mean() - uv[k, 0]) < 0.25 and abs(ys.mean() - uv[k, 1]) < 0.25, (xs.mean(), ys.mean(), uv[k])
