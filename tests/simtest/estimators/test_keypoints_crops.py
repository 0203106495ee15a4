"""The zoom-in keypoint estimator: crop geometry, a network overfitted on one image, checkpoints, ONNX."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest

from simtest.errors import ConfigError
from simtest.estimators.keypoints.crops import crop_intrinsics, crop_window_for_box, map_pixels, warp_crop


def _K() -> np.ndarray:
    return np.array([[307.5, 0.0, 159.3], [0.0, 306.9, 121.7], [0.0, 0.0, 1.0]])


def test_crop_intrinsics_map_crop_pixels_to_full_image_pixels_exactly():
    rng = np.random.default_rng(0)
    K = _K()
    for box, size in [((37.25, 12.5, 90.0, 90.0), 128), ((-20.0, 100.3, 51.7, 51.7), (64, 64)),
                      ((10.0, 20.0, 160.0, 80.0), (40, 80))]:
        Kc, M = crop_intrinsics(K, box, size)
        assert np.array_equal(M[2], [0.0, 0.0, 1.0])
        np.testing.assert_allclose(Kc, M @ K, rtol=0, atol=1e-12)
        # 3D points projected with K' are the points projected with K, mapped by M (and back by M^-1)
        X = rng.uniform([-0.2, -0.2, 0.4], [0.2, 0.2, 1.2], size=(50, 3))
        p = (X @ K.T)[:, :2] / X[:, 2:]
        pc = (X @ Kc.T)[:, :2] / X[:, 2:]
        back = np.c_[pc, np.ones(len(pc))] @ np.linalg.inv(M).T
        np.testing.assert_allclose(back[:, :2], p, rtol=0, atol=1e-9)
        np.testing.assert_allclose(map_pixels(np.linalg.inv(M), pc), p, rtol=0, atol=1e-9)
        np.testing.assert_allclose(map_pixels(M, p), pc, rtol=0, atol=1e-9)
        # the window's edges land on the crop's edges (OpenCV: pixel i covers [i - 0.5, i + 0.5])
        h, w = (size, size) if isinstance(size, int) else size
        x0, y0, bw, bh = box
        corners = np.array([[x0, y0, 1.0], [x0 + bw, y0 + bh, 1.0]]) @ M.T
        np.testing.assert_allclose(corners[:, :2], [[-0.5, -0.5], [w - 0.5, h - 0.5]], rtol=0, atol=1e-12)
    # the whole image as its own window is the identity
    _, M = crop_intrinsics(K, (-0.5, -0.5, 320, 240), (240, 320))
    np.testing.assert_allclose(M, np.eye(3), rtol=0, atol=1e-15)
    with pytest.raises(ConfigError, match="positive"):
        crop_intrinsics(K, (0, 0, 0, 10), 16)


def test_warped_crop_samples_the_full_image_at_m_inverse():
    H, W = 240, 320
    ramp_u = np.tile(np.arange(W, dtype=np.float32), (H, 1))
    ramp_v = np.tile(np.arange(H, dtype=np.float32)[:, None], (1, W))
    img = np.stack([ramp_u, ramp_v, np.zeros_like(ramp_u)], -1)
    box = crop_window_for_box((100, 60, 70, 50), margin=1.3)
    assert box[2] == box[3] == pytest.approx(1.3 * 71)
    _, M = crop_intrinsics(_K(), box, 128)
    crop = warp_crop(img, M, 128)
    vs, us = np.mgrid[0:128, 0:128]
    full = np.stack([us.ravel(), vs.ravel(), np.ones(us.size)], 1) @ np.linalg.inv(M).T
    # bilinear resampling of a linear image is exact up to OpenCV's 1/32-pixel interpolation grid
    np.testing.assert_allclose(crop[..., 0].ravel(), full[:, 0], atol=1 / 32 + 1e-4)
    np.testing.assert_allclose(crop[..., 1].ravel(), full[:, 1], atol=1 / 32 + 1e-4)
    mask = np.zeros((H, W), bool)
    mask[60:111, 100:171] = True
    assert warp_crop(mask, M, 128).dtype == bool


def test_the_shipped_estimator_needs_no_options_and_reads_no_depth(small_dataset):
    """`simtest eval --estimator keypoints` on builtin-small: the shipped crop network and RGB-only detector, both
    through ONNX Runtime; no ground truth is asked for; another object set is refused."""
    from simtest.estimators import load_estimator
    from simtest.evaluation.run import evaluate
    from simtest.objects import load_object_set

    est = load_estimator("keypoints")
    assert est.runtime == "onnx" and est.segmenter.runtime == "onnx"
    assert not est.needs_gt_masks and not est.segmenter.depth_input
    assert est.refine == "silhouette"  # the pose is fitted to the network's own mask, still from RGB only
    rep = evaluate(small_dataset, est, vsd=False, progress=False, max_images=2)
    assert rep.overall["num_image_exceptions"] == 0
    with pytest.raises(ConfigError, match="trained for objects"):
        est.check_objects(load_object_set("builtin"))


torch = pytest.importorskip("torch")

from simtest.data import PoseDataset  # noqa: E402
from simtest.estimators.base import Observation  # noqa: E402
from simtest.estimators.checkpoint import object_record, save_checkpoint  # noqa: E402
from simtest.estimators.keypoints.crop_infer import CROP_FORMAT, CropKeypointEstimator  # noqa: E402
from simtest.estimators.keypoints.crop_model import crop_loss  # noqa: E402
from simtest.estimators.keypoints.crops import KeypointCrops, collate_crops  # noqa: E402
from simtest.training.keypoints import build_crop_model  # noqa: E402
from simtest.metrics.pose import add, add_s  # noqa: E402
from simtest.objects.loaders import load_dataset_objects  # noqa: E402


def _observation(ds: PoseDataset, i: int, objects) -> tuple[Observation, dict]:
    s = ds.load_numpy(i)
    keep = [k for k in range(len(s["masks"])) if s["masks"][k].sum() >= 200]
    obs = Observation(rgb=s["rgb"], depth=np.zeros(s["rgb"].shape[:2], np.float32), K=s["K"],
                      width=s["rgb"].shape[1], height=s["rgb"].shape[0], objects=objects,
                      target_obj_ids=tuple(int(s["obj_ids"][k]) for k in keep),
                      masks=tuple(s["masks"][k] for k in keep))
    return obs, {"keep": keep, "R": s["R"], "t": s["t"], "obj_ids": s["obj_ids"]}


#: Optimiser steps of the overfitted network.
STEPS = 600


@pytest.fixture(scope="module")
def overfitted(small_dataset):
    """A small crop network fitted to the crops of one image (no augmentation, no box jitter)."""
    objects = load_dataset_objects(small_dataset)
    ds = PoseDataset(small_dataset, objects=objects, max_images=1)
    crops = KeypointCrops(ds, size=64, min_pixels=200, jitter_scale=0.0, jitter_shift=0.0, xyz_stride=4)
    batch = collate_crops([crops[0]])
    assert len(batch["labels"]) >= 1
    torch.manual_seed(0)
    scale = tuple(0.5 * o.diameter for o in sorted(objects, key=lambda o: o.obj_id))
    net = build_crop_model(ds.num_classes, 8, seed=0, widths=(16, 24, 32, 48), decoder=(32, 32), crop_size=64,
                           xyz_scale=scale, hypotheses=2)
    opt = torch.optim.Adam(net.parameters(), lr=3e-3)
    net.train()
    losses = []
    # one thread: the same float reductions, so the same network, whatever thread count earlier tests left set
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        for _ in range(STEPS):
            out = crop_loss(net(batch["rgb"]), batch, net.cfg)
            opt.zero_grad()
            out["loss"].backward()
            opt.step()
            losses.append(float(out["kp"]))
    finally:
        torch.set_num_threads(threads)
    return net.eval(), objects, ds, losses


def _hits(found, gt, objects) -> int:
    """How many estimates are within ADD(-S) 0.1 d of their target's ground truth."""
    ok = 0
    for e in found:
        k = gt["keep"][e.target_index]
        obj = objects.get(int(gt["obj_ids"][k]))
        err = (add_s if obj.is_symmetric else add)(e.R, e.t, gt["R"][k], gt["t"][k], obj.vertices)
        ok += err < 0.1 * obj.diameter
    return ok


# recrop 0 (the default with ground-truth boxes): a network that memorised one image's ground-truth crops is
# asked about the crops it memorised; re-framing is tested on its own below
@pytest.mark.parametrize("solver, fusion, recrop, refine", [
    ("auto", "auto", None, "silhouette"), ("auto", "auto", None, None), ("dense", "confidence", 0, "silhouette"),
    ("keypoints", "confidence", 0, None), ("keypoints", "uniform", 0, "silhouette")])
def test_a_network_overfitted_on_one_image_recovers_its_poses(overfitted, solver, fusion, recrop, refine):
    net, objects, ds, losses = overfitted
    assert losses[-1] < losses[0] - 5.0, losses[::50]
    assert net.cfg.dense
    est = CropKeypointEstimator(model=net, objects_record=object_record(objects), detect="gt", solver=solver,
                                fusion=fusion, recrop=recrop, refine=refine, refine_coverage=0.3)
    # refine_coverage 0.3: a network that memorised its training cells crosses 0.5 at the training rule itself
    # (the shipped network's 0.2 is calibrated on held-out images)
    assert est.needs_gt_masks  # ground-truth boxes: runs labelled (GT masks)
    if solver == "auto":  # a dense network: the dense solver on every mask cell
        assert (est.solver, est.fusion) == ("dense", "uniform")
    obs, gt = _observation(ds, 0, objects)
    found = est.estimate(obs)
    assert len(found) == len(gt["keep"])
    if est.solver == "dense":
        assert all(e.info["correspondences"] >= 8 and e.info["hypothesis"] in (0, 1) for e in found)
    if refine:  # the silhouette fit ran on every estimate and, where it moved the pose, raised the IoU
        fits = [e.info["silhouette"] for e in found]
        assert all(f["iou_after"] >= f["iou_before"] and (f["applied"] or f["iou_after"] == f["iou_before"])
                   for f in fits)
    else:
        assert all("silhouette" not in e.info for e in found)
    ok = _hits(found, gt, objects)
    assert ok >= max(1, int(0.75 * len(found))), (ok, len(found))


def test_recrop_frames_the_crop_by_the_networks_own_object_cells(overfitted):
    """The box of the overfitted network's object cells, mapped back to the full image, is the ground-truth
    visible box it was trained on, up to a few cells; with fewer than 4 object cells the box stays."""
    from simtest.io.bop import mask_bbox

    net, objects, ds, _ = overfitted
    est = CropKeypointEstimator(model=net, objects_record=object_record(objects), detect="gt")
    assert est.recrop == 0  # ground-truth boxes already frame the crop as in training
    assert CropKeypointEstimator(model=net, objects_record=object_record(objects), detect="gt", recrop=2).recrop == 2
    obs, gt = _observation(ds, 0, objects)
    K = np.asarray(obs.K, np.float64)
    rgb = np.asarray(obs.rgb, np.float32) / np.float32(255.0)
    boxes = [np.asarray(mask_bbox(m), np.float64) for m in obs.masks]
    crops = est._crops(rgb, K, boxes, list(obs.target_obj_ids))

    def iou(a, b):
        ix = max(0.0, min(a[0] + a[2], b[0] + b[2]) - max(a[0], b[0]))
        iy = max(0.0, min(a[1] + a[3], b[1] + b[3]) - max(a[1], b[1]))
        return ix * iy / (a[2] * a[3] + b[2] * b[3] - ix * iy)

    cell = 4.0 * (1.3 * max(boxes[0][2:]) / 64.0)  # a cell's side in full-image pixels, about
    found = [est._mask_box(maps, M, box) for (maps, M), box in zip(crops, boxes)]
    good = [iou(f, b) > 0.6 and np.abs(f - b).max() <= 3 * cell for f, b in zip(found, boxes)]
    assert sum(good) >= max(1, int(0.75 * len(boxes))), (found, boxes)
    # fewer than 4 object cells: the box stays
    maps = dict(crops[0][0], prob=np.zeros_like(crops[0][0]["prob"]))
    assert np.array_equal(est._mask_box(maps, crops[0][1], boxes[0]), boxes[0])


def test_object_coordinate_targets_are_the_visible_surface_in_the_model_frame(small_dataset):
    """Each crop cell's target, mapped by the canonical pose and projected with the crop's K, falls inside its
    cell; each lies on the model surface (within the depth quantisation and the cell's extent)."""
    import trimesh

    from simtest.estimators.keypoints.crops import cell_object_coords, object_coords_image

    objects = load_dataset_objects(small_dataset)
    ds = PoseDataset(small_dataset, objects=objects, max_images=2)
    crops = KeypointCrops(ds, size=64, min_pixels=200, xyz_stride=4, seed=3)
    s = ds[1]
    item = crops[1]
    assert item["xyz"].shape == (len(item["labels"]), 3, 16, 16) and item["xyz_valid"].any()
    for c in range(len(item["labels"])):
        valid = item["xyz_valid"][c]
        pts = item["xyz"][c][:, valid].T.astype(np.float64)  # (M, 3) model frame
        # which instance: the one whose canonical pose projects these points onto their cells
        Kc = item["K"][c]
        vs, us = np.nonzero(valid)
        centers = np.stack([4 * us + 1.5, 4 * vs + 1.5], 1)
        best = np.inf
        for k in range(len(s["labels"])):
            if int(s["labels"][k]) != int(item["labels"][c]):
                continue
            X = pts @ s["R_sym"][k].numpy().T + s["t_sym"][k].numpy()
            uv = (X @ Kc.T)[:, :2] / X[:, 2:]
            best = min(best, float(np.abs(uv - centers).max()))
        assert best <= 2.5, best  # within the 4 x 4 cell (its pixels' mean lies inside it)
        obj = objects.get(int(ds.class_ids[int(item["labels"][c]) - 1]))
        surface = trimesh.Trimesh(obj.vertices, obj.faces, process=False).sample(20000, seed=0)
        d = np.min(np.linalg.norm(pts[:, None, :] - surface[None], axis=-1), axis=1)
        assert np.median(d) < 0.005 and np.percentile(d, 90) < 0.01, (np.median(d), np.percentile(d, 90))
    # the per-pixel image: zero off the mask, the cell mean of the pixels that have coordinates
    depth = np.zeros((4, 4), np.float32)
    depth[1:3, 1:3] = 0.5
    mask = np.zeros((4, 4), bool)
    mask[1:, 1:] = True
    img = object_coords_image(depth, np.eye(3), mask, np.eye(3), np.zeros(3))
    assert np.array_equal(img[..., 2] > 0, depth > 0)
    mean, ok = cell_object_coords(img, mask, 2, min_coverage=0.25)
    assert ok.tolist() == [[True, True], [True, True]] and mean[2, 0, 0] == pytest.approx(0.5)
    mean, ok = cell_object_coords(img, mask, 2, min_coverage=0.5)
    assert ok.tolist() == [[False, False], [False, False]]


def test_checkpoint_loading_refuses_another_object_set(overfitted, tmp_path):
    from simtest.objects import load_object_set

    net, objects, ds, _ = overfitted
    ckpt = {"format": CROP_FORMAT, "net": net.cfg.to_dict(), "objects": object_record(objects),
            "model": {k: v.detach().cpu() for k, v in net.state_dict().items()}, "epoch": 0, "optimizer": None,
            "history": [], "train": {}}
    path = save_checkpoint(tmp_path / "model.pt", ckpt)
    assert torch.load(path, weights_only=True)["format"] == CROP_FORMAT
    # runtime parity is checked on the solver's poses: the silhouette fit's pattern search may step differently
    # on float32-rounded masks
    est = CropKeypointEstimator(checkpoint=path, detect="gt", runtime="torch", refine=None)
    est.check_objects(objects)  # its own set passes
    other = load_object_set("builtin")
    with pytest.raises(ConfigError, match="trained for objects"):
        est.check_objects(other)
    obs, _ = _observation(ds, 0, other)
    with pytest.raises(ConfigError, match="trained for objects"):
        est.estimate(obs)
    # the ONNX file of the checkpoint carries the record and refuses too
    pytest.importorskip("onnxscript")
    from simtest.estimators.onnx_export import export_checkpoint

    export_checkpoint(path)
    onnx_est = CropKeypointEstimator(checkpoint=path, detect="gt", refine=None)
    assert onnx_est.runtime == "onnx"
    with pytest.raises(ConfigError, match="trained for objects"):
        onnx_est.check_objects(other)
    assert est.recrop == onnx_est.recrop == 0  # ground-truth boxes: both runtimes see the same crops
    # the two runtimes compute the same network: its outputs agree to float32 rounding
    probe = np.random.default_rng(0).random((2, 3, 64, 64), dtype=np.float32)
    ra, rb = est._run(probe), onnx_est._run(probe)
    assert ra.keys() == rb.keys()
    for name in ra:
        np.testing.assert_allclose(ra[name], rb[name], rtol=1e-3, atol=1e-4, err_msg=name)
    # the poses go through RANSAC-PnP on votes that differ in their last bits: a changed inlier set can move the
    # translation of this barely trained network by millimetres (4.9 mm seen), so they agree within 1 cm
    a = est.estimate(_observation(ds, 0, objects)[0])
    b = onnx_est.estimate(_observation(ds, 0, objects)[0])
    assert len(a) == len(b)
    for x, y in zip(a, b):
        np.testing.assert_allclose(x.t, y.t, atol=1e-2)
    # a whole-image checkpoint is not a crop checkpoint
    with pytest.raises(ConfigError, match="simtest-keypoints/2"):
        CropKeypointEstimator(checkpoint=save_checkpoint(tmp_path / "v1.pt", {**ckpt, "format": "simtest-keypoints/1"}),
                              detect="gt", runtime="torch")


def test_detector_candidates_keep_one_pose_per_expected_instance(small_dataset):
    """``--opt candidates=3``: more detector regions are posed, and per object only as many best-scored
    estimates as the image has instances of it come back."""
    from collections import Counter

    from simtest.estimators import load_estimator

    objects = load_dataset_objects(small_dataset)
    ds = PoseDataset(small_dataset, objects=objects, max_images=2)
    one, three = load_estimator("keypoints"), load_estimator("keypoints", candidates=3)
    for i in range(2):
        obs, _ = _observation(ds, i, objects)
        obs = replace(obs, masks=None)
        a, b = one.estimate(obs), three.estimate(obs)
        wanted = Counter(obs.target_obj_ids)
        for found in (a, b):
            assert all(n <= wanted[o] for o, n in Counter(e.obj_id for e in found).items())
        assert len(b) >= len(a)


def test_detector_regions_ranked_by_probability_or_area(small_dataset):
    """``region_rank``: the same regions of a class come back, ordered by mean class probability (``prob``,
    the keypoint estimator's default) or by size (``area``); other names are refused."""
    from simtest.estimators import load_estimator

    objects = load_dataset_objects(small_dataset)
    ds = PoseDataset(small_dataset, objects=objects, max_images=1)
    obs, _ = _observation(ds, 0, objects)
    obs = replace(obs, masks=None, target_obj_ids=None)
    seg = load_estimator("keypoints").segmenter
    assert load_estimator("keypoints").region_rank == "prob"
    by_prob, by_area = seg.regions(obs, rank="prob"), seg.regions(obs, rank="area")
    assert by_prob and sorted(p for _, _, p in by_prob) == sorted(p for _, _, p in by_area)
    for oid in {o for o, _, _ in by_prob}:
        probs = [p for o, _, p in by_prob if o == oid]
        sizes = [int(m.sum()) for o, m, _ in by_area if o == oid]
        assert probs == sorted(probs, reverse=True)
        assert len(sizes) == len(probs)
    with pytest.raises(ConfigError, match="region_rank must be one of area, prob, got 'size'"):
        CropKeypointEstimator(region_rank="size")


def test_detector_regions_from_a_probability_threshold(small_dataset):
    """``threshold`` > 0: a class's regions are the connected pixels where its probability exceeds it, so
    each covers the class-map region it contains (the most probable class there is above any threshold <= 0.5)
    and may reach pixels another class wins; a threshold outside [0, 1) is refused by value."""
    from simtest.estimators import load_estimator

    objects = load_dataset_objects(small_dataset)
    ds = PoseDataset(small_dataset, objects=objects, max_images=1)
    obs, _ = _observation(ds, 0, objects)
    obs = replace(obs, masks=None, target_obj_ids=None)
    seg = load_estimator("keypoints").segmenter
    prob = seg.probabilities(obs.rgb, obs.depth, np.asarray(obs.K, np.float64))
    by_map, by_thr = seg.regions(obs, rank="prob"), seg.regions(obs, rank="prob", threshold=0.3)
    assert by_map and by_thr
    for oid, mask, p in by_thr:
        c = seg.class_ids.index(oid) + 1
        assert mask.any() and float(prob[c][mask].min()) > 0.3  # the region (eroded) is all above it
        assert 0.3 < p <= 1.0
    for oid, mask, _ in by_map:  # every class-map region lies within some threshold region of its class
        mine = [m for o, m, _ in by_thr if o == oid]
        assert mine and max((m & mask).sum() for m in mine) >= 0.9 * mask.sum()
    for bad in (-0.1, 1.0):
        with pytest.raises(ConfigError, match=rf"region threshold must be a class probability in \[0, 1\), got {bad}"):
            seg.regions(obs, threshold=bad)


def test_estimator_options_are_checked():
    with pytest.raises(ConfigError, match="detect 'depth'"):
        CropKeypointEstimator(detect="depth")
    with pytest.raises(ConfigError, match="fusion 'median'"):
        CropKeypointEstimator(fusion="median")
    with pytest.raises(ConfigError, match="solver 'voting'"):
        CropKeypointEstimator(solver="voting")
    with pytest.raises(ConfigError, match="dense_keep"):
        CropKeypointEstimator(dense_keep=0.0)
    with pytest.raises(ConfigError, match="recrop must be an integer 0-3 or none, got 5"):
        CropKeypointEstimator(recrop=5)
    with pytest.raises(ConfigError, match="unknown refine 'icp'; valid: none, silhouette"):
        CropKeypointEstimator(refine="icp")
    with pytest.raises(ConfigError, match="refine_coverage"):
        CropKeypointEstimator(refine_coverage=1.5)
    with pytest.raises(ConfigError, match="candidates must be an integer 1-8, got 0"):
        CropKeypointEstimator(candidates=0)
    from simtest.objects import load_object_set

    plain = build_crop_model(4, 8, seed=0, widths=(8, 8, 8, 8), decoder=(8, 8), crop_size=32)
    with pytest.raises(ConfigError, match="object-coordinate head"):
        CropKeypointEstimator(model=plain, objects_record=object_record(load_object_set("builtin-small")),
                              detect="gt", solver="dense")
    est = CropKeypointEstimator(model=plain, objects_record=object_record(load_object_set("builtin-small")),
                                detect="gt")
    assert (est.solver, est.fusion, est.recrop) == ("keypoints", "confidence", 0)  # gt boxes: no recrop


def test_pose_templates_poses_the_detections_by_template_matching(small_dataset, tmp_path, monkeypatch):
    """``--opt pose=templates``: the same detector's regions, posed by the template estimator (which shares the
    detector), ``TEMPLATE_CANDIDATES`` regions per expected instance unless ``candidates`` is given."""
    from collections import Counter

    from simtest.estimators import load_estimator
    from simtest.estimators.keypoints.crop_infer import TEMPLATE_CANDIDATES
    from simtest.estimators.keypoints.template_stage import (TEMPLATE_FRAMING_STARTS, TEMPLATE_OCCLUDERS,
                                                             TEMPLATE_REGION_EXTRA)

    monkeypatch.setenv("SIMTEST_CACHE", str(tmp_path))
    objects = load_dataset_objects(small_dataset)
    ds = PoseDataset(small_dataset, objects=objects, max_images=1)
    obs, _ = _observation(ds, 0, objects)
    obs = replace(obs, masks=None)
    est = load_estimator("keypoints", pose="templates", candidates=1)
    found = est.estimate(obs)
    assert est.templates.segmenter is est.segmenter and est.templates.candidates == 1
    assert est.templates.refine == "none"  # the detector's regions are too coarse to fit a silhouette to
    assert est.templates.framing and est.templates.local_deg == 4.0  # the framing and local searches
    assert est.templates.local_min_deg == 1.0  # the local search's 4, 2 and 1 degree steps (twentieth round)
    assert est.templates.outline_mask == "soft+flip"  # how an outline fit reads its network (tenth round)
    assert est.templates.outline_temperature == 2.0  # at temperature 2 (eleventh round)
    assert load_estimator("keypoints", outline_temperature=1)._options["outline_temperature"] == 1.0
    assert est.templates.framing_starts == TEMPLATE_FRAMING_STARTS == (1.0, 1.4)  # the windows the framing search starts from
    assert all(e.info["framing_start"] in TEMPLATE_FRAMING_STARTS for e in found)
    assert load_estimator("keypoints", framing_starts=(1,))._options["framing_starts"] == (1.0,)
    with pytest.raises(ConfigError, match="framing_starts must be window factors in \\[0.25, 4\\].*got \\(0, 2\\)"):
        load_estimator("keypoints", framing_starts=(0, 2))
    assert est.templates.region_extra == TEMPLATE_REGION_EXTRA
    assert load_estimator("keypoints", region_extra=0.2)._options["region_extra"] == 0.2
    with pytest.raises(ConfigError, match="region_extra must be a class probability in \\[0, 1\\), got -0.1"):
        load_estimator("keypoints", region_extra=-0.1)
    assert est.templates.occluders is TEMPLATE_OCCLUDERS is False  # other objects' regions count (nineteenth round)
    assert load_estimator("keypoints", occluders=True)._options["occluders"] is True
    with pytest.raises(ConfigError, match="occluders must be true or false, got 'yes'"):
        load_estimator("keypoints", occluders="yes")
    assert load_estimator("keypoints", outline_mask="hard")._options["outline_mask"] == "hard"
    with pytest.raises(ConfigError, match="unknown outline_mask 'fuzzy'; valid: hard, soft, soft\\+flip"):
        load_estimator("keypoints", outline_mask="fuzzy")
    assert found and all("match" in e.info and "local_renders" in e.info for e in found)
    wanted = Counter(obs.target_obj_ids)
    assert all(n <= wanted[o] for o, n in Counter(e.obj_id for e in found).items())
    assert load_estimator("keypoints", pose="templates").candidates == 1  # the network's, unchanged
    assert TEMPLATE_CANDIDATES >= 1
