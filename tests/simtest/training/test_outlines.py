"""The outline network: its samples (seeded crops of real generated frames, the prior near the visible mask), its
trainer (resumable through the one loop), its ONNX file (the same masks as torch) and the pose fit it drives in
the template estimator (real renders, real training, no mocks)."""

from __future__ import annotations

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from simtest.errors import ConfigError  # noqa: E402
from simtest.estimators.base import Observation  # noqa: E402
from simtest.estimators.templates.outline import OutlineNet, OutlineNets, load_outline, outline_fit  # noqa: E402
from simtest.objects import load_object_set  # noqa: E402
from simtest.training.outlines import OutlineCrops, OutlineTrainConfig, _instances, train_outlines  # noqa: E402

from tests.simtest.training.test_fit import _resume_equals_uninterrupted  # noqa: E402

K = np.array([[572.4, 0.0, 325.3], [0.0, 573.6, 242.0], [0.0, 0.0, 1.0]])


@pytest.fixture(scope="module")
def outline_run(small_dataset, tmp_path_factory):
    """One epoch of the outline network on the small dataset (64-pixel crops): its model.pt and model.onnx."""
    out = tmp_path_factory.mktemp("outlines") / "run"
    res = train_outlines(OutlineTrainConfig(data=str(small_dataset), out=str(out), val=str(small_dataset),
                                            val_images=2, epochs=1, batch_size=8, crop_size=64, seed=3, threads=1),
                         progress=False, log=lambda s: None)
    return res


def test_samples_are_seeded_per_epoch_and_their_prior_lies_near_the_visible_mask(small_dataset):
    instances = _instances([str(small_dataset)], None, 0.8, None)
    assert instances
    crops = OutlineCrops(instances, 64, seed=1, photometric=True)
    first = [crops.arrays(i) for i in range(len(crops))]
    again = crops.arrays(0)
    assert all(np.array_equal(a, b) for a, b in zip(first[0], again))  # same seed, epoch and index
    crops.set_epoch(1)
    assert not np.array_equal(crops.arrays(0)[0], first[0][0])  # another epoch, another draw
    ious = []
    for crop, prior, visible in first:
        assert crop.shape == (64, 64, 3) and crop.dtype == np.uint8
        assert set(np.unique(prior)) <= {0, 1} and set(np.unique(visible)) <= {0, 1} and visible.any()
        ious.append(np.count_nonzero(prior & visible) / np.count_nonzero(prior | visible))
    # the prior is the object's silhouette a few percent off: mostly on the (mostly visible) object
    assert np.mean(ious) > 0.6, ious
    sample = crops[0]
    assert sample["x"].shape == (4, 64, 64) and sample["y"].shape == (1, 64, 64)


def test_pose_priors_are_the_silhouette_of_a_perturbed_pose_framed_as_the_fit_frames_it(small_dataset):
    from simtest.objects.loaders import load_dataset_objects

    instances = _instances([str(small_dataset)], None, 0.8, None)
    objects = load_dataset_objects(str(small_dataset))
    plain = OutlineCrops(instances, 64, seed=1, photometric=True)
    off = OutlineCrops(instances, 64, seed=1, photometric=True, objects=objects, pose_priors=0.0)
    posed = OutlineCrops(instances, 64, seed=1, photometric=True, objects=objects, pose_priors=1.0)
    ious = []
    for i in range(len(instances)):
        # no pose priors: the very samples of a run without them (no extra draw)
        assert all(np.array_equal(a, b) for a, b in zip(plain.arrays(i), off.arrays(i)))
        crop, prior, visible = posed.arrays(i)
        assert all(np.array_equal(a, b) for a, b in zip((crop, prior, visible), posed.arrays(i)))
        assert crop.shape == (64, 64, 3) and set(np.unique(prior)) <= {0, 1} and visible.any()
        # framed on the prior as outline_fit frames a found pose: margin 1.2 around it
        ys, xs = np.nonzero(prior)
        assert max(ys.max() - ys.min(), xs.max() - xs.min()) + 1 >= 64 / 1.2 - 3
        ious.append(np.count_nonzero(prior & visible) / np.count_nonzero(prior | visible))
    assert 0.5 < np.mean(ious) < 0.99, ious  # near the object, yet another outline
    with pytest.raises(ConfigError, match="objects"):
        OutlineCrops(instances, 64, seed=1, photometric=True, pose_priors=0.5)
    with pytest.raises(ConfigError, match="pose_priors"):
        OutlineTrainConfig(data="x", out="y", pose_priors=1.5)


def test_camera_changes_at_the_image_scale_are_seeded_and_keep_the_masks(small_dataset):
    instances = _instances([str(small_dataset)], None, 0.8, None)
    at_crop = OutlineCrops(instances, 64, seed=2, photometric=True)
    at_image = OutlineCrops(instances, 64, seed=2, photometric=True, camera_scale="image")
    for i in range(len(instances)):
        crop, prior, visible = at_image.arrays(i)
        assert all(np.array_equal(a, b) for a, b in zip((crop, prior, visible), at_image.arrays(i)))
        assert crop.shape == (64, 64, 3) and visible.any()
        assert not np.array_equal(crop, at_crop.arrays(i)[0])
    # the window cut around the object moves nothing: a sample drawn from it (its intrinsics shifted) is the
    # sample drawn from the whole image
    from simtest.io import bop
    from simtest.training.outlines import _around, outline_sample

    scene, im, g = instances[0]
    d = bop.read_scene(scene)[im]
    images = (bop.read_image(scene, im), bop.read_mask(scene, im, g, visible=True),
              bop.read_mask(scene, im, g, visible=False))
    (rgb, visible, amodal), K2 = _around(d["gt"][g].bbox_obj, d["K"], *images)
    assert rgb.shape[0] < images[0].shape[0] or rgb.shape[1] < images[0].shape[1]
    cut = outline_sample(rgb, K2, amodal, visible, 64, np.random.default_rng(4))
    whole = outline_sample(images[0], d["K"], images[2], images[1], 64, np.random.default_rng(4))
    for a, b in zip(cut, whole):
        assert np.mean(a == b) > 0.99
    with pytest.raises(ConfigError, match="camera_scale"):
        OutlineTrainConfig(data="x", out="y", camera_scale="sensor")


def test_object_light_changes_only_the_objects_visible_pixels_of_a_crop(small_dataset):
    """``--object-light 1``: the crop's visible object pixels scaled by one gain, everything else (the rest of
    the crop, the prior, the mask) drawn as with the default 0; a share outside [0, 1] is refused."""
    instances = _instances([str(small_dataset)], None, 0.5, None)
    plain = OutlineCrops(instances, 64, seed=2, photometric=True, augment_p=0.0)
    lit = OutlineCrops(instances, 64, seed=2, photometric=True, augment_p=0.0, object_light=1.0)
    changed = 0
    for i in range(len(instances)):
        (c0, p0, v0), (c1, p1, v1) = plain.arrays(i), lit.arrays(i)
        assert np.array_equal(p0, p1) and np.array_equal(v0, v1)
        assert np.array_equal(c0[v0 == 0], c1[v0 == 0])
        changed += int((c0[v0 == 1] != c1[v0 == 1]).any())
    assert changed >= len(instances) - 1  # a gain within a rounding step of 1 leaves a crop as it was
    with pytest.raises(ConfigError, match="object_light"):
        OutlineTrainConfig(data="x", out="y", object_light=1.5)


def test_an_amodal_target_is_the_whole_silhouette_in_the_same_crop(small_dataset):
    """``target="amodal"``: the same crop and prior as the visible sample (no extra draw), the target the whole
    silhouette, hidden parts too: it holds the visible mask and more where the object is occluded."""
    from simtest.io import bop
    from simtest.objects.loaders import load_dataset_objects

    instances = _instances([str(small_dataset)], None, 0.1, None)
    objects = load_dataset_objects(str(small_dataset))
    for priors in (0.0, 1.0):
        seen = OutlineCrops(instances, 64, seed=2, photometric=True, objects=objects, pose_priors=priors)
        whole = OutlineCrops(instances, 64, seed=2, photometric=True, objects=objects, pose_priors=priors,
                             target="amodal")
        grown = 0
        for i, (scene, im, g) in enumerate(instances):
            (c0, p0, v0), (c1, p1, a1) = seen.arrays(i), whole.arrays(i)
            assert np.array_equal(c0, c1) and np.array_equal(p0, p1)
            assert np.count_nonzero(v0 & ~a1) <= 0.02 * max(1, np.count_nonzero(v0))  # warped alike, to a pixel
            fract = bop.read_scene(scene)[im]["gt"][g].visib_fract
            if fract < 0.8:
                grown += np.count_nonzero(a1) > 1.1 * np.count_nonzero(v0)
        assert grown > 0  # occluded instances draw their hidden part
    with pytest.raises(ConfigError, match="target"):
        OutlineTrainConfig(data="x", out="y", target="both")
    with pytest.raises(ConfigError, match="object_light"):
        OutlineTrainConfig(data="x", out="y", target="amodal", object_light=0.5)
    with pytest.raises(ConfigError, match="target"):  # the dataset refuses them as the settings do
        OutlineCrops(instances, 64, seed=2, photometric=True, target="Amodal")
    with pytest.raises(ConfigError, match="object_light"):
        OutlineCrops(instances, 64, seed=2, photometric=True, target="amodal", object_light=1.0)


def test_an_outline_run_resumed_after_an_epoch_equals_an_uninterrupted_one(small_dataset, tmp_path):
    _resume_equals_uninterrupted(train_outlines, OutlineTrainConfig, tmp_path, data=str(small_dataset), epochs=2,
                                 batch_size=4, crop_size=32, max_images=2, seed=5, threads=1)


def test_bad_settings_name_the_value():
    with pytest.raises(ConfigError, match="crop_size"):
        OutlineTrainConfig(data="x", out="y", crop_size=100)
    with pytest.raises(ConfigError, match="frozen"):
        OutlineTrainConfig(data="x", out="y", encoder_lr_scale=0.5)
    with pytest.raises(ConfigError, match="min_visib"):
        OutlineTrainConfig(data="x", out="y", min_visib=1.5)


def test_the_onnx_file_draws_the_masks_torch_draws_and_the_fit_moves_the_pose_within_its_bound(outline_run):
    assert outline_run.history[0]["val_prior_iou"] > 0.5 and 0.0 <= outline_run.history[0]["val_iou"] <= 1.0
    onnx, pt = OutlineNet(outline_run.model_path.with_suffix(".onnx")), OutlineNet(outline_run.model_path, "torch")
    assert onnx.runtime == "onnx" and pt.runtime == "torch" and onnx.size == pt.size == 64
    rng = np.random.default_rng(0)
    crop = rng.integers(0, 255, (64, 64, 3), dtype=np.uint8)
    prior = np.zeros((64, 64), bool)
    prior[16:48, 20:44] = True
    a, b = onnx.mask(crop, prior), pt.mask(crop, prior)
    assert np.mean(a == b) > 0.99
    with pytest.raises(ConfigError, match="64"):
        onnx.mask(crop[:32], prior)

    from simtest.estimators.templates.render import ObjectRenderer
    from simtest.estimators.templates.views import view_rotation

    obj = load_object_set("builtin-small").by_name("mug_0")
    R, t = view_rotation([0.4, -0.6, 0.7]), np.array([0.05, -0.03, 0.65])
    with ObjectRenderer(obj, K, 640, 480) as renderer:
        rgb, _ = renderer.render(R, t)
    fit = outline_fit(onnx, obj, rgb, K, R, t, max_scale=0.1, step_deg=0.0)
    assert abs(fit.scale - 1.0) <= 0.11 and np.allclose(fit.R, R, atol=1e-12)  # no turns: the rotation stays
    turned = outline_fit(onnx, obj, rgb, K, R, t, max_scale=0.1, step_deg=2.0)
    assert turned.iou_after >= fit.iou_after - 1e-9 and abs(turned.scale - 1.0) <= 0.11  # the bound is along the ray
    assert set(fit.info()) == {"applied", "iou_before", "iou_after", "scale"}
    behind = outline_fit(onnx, obj, rgb, K, R, -t)  # nothing of it in the image: left as it is
    assert not behind.applied and np.array_equal(behind.t, -t)


def test_networks_joined_by_plus_are_read_as_one_their_probabilities_averaged(outline_run):
    onnx_path = str(outline_run.model_path.with_suffix(".onnx"))
    parsed, single = load_outline(f"{onnx_path}+{onnx_path}"), load_outline(onnx_path)
    assert isinstance(parsed, OutlineNets) and isinstance(single, OutlineNet) and parsed.size == 64
    assert parsed.path == f"{onnx_path}+{onnx_path}" and len(parsed.nets) == 2
    # the ONNX file and the checkpoint run by torch: two readings that differ in the last bits
    a, b = OutlineNet(onnx_path), OutlineNet(outline_run.model_path, "torch")
    joined = OutlineNets([a, b])
    rng = np.random.default_rng(1)
    crop = rng.integers(0, 255, (64, 64, 3), dtype=np.uint8)
    prior = np.zeros((64, 64), bool)
    prior[12:50, 18:46] = True
    for mode in ("soft", "soft+flip"):
        want = 0.5 * (a.read(crop, prior, mode, 2.0) + b.read(crop, prior, mode, 2.0))
        assert np.array_equal(joined.read(crop, prior, mode, 2.0), want)
    mean = 0.5 * (a.read(crop, prior, "soft") + b.read(crop, prior, "soft"))
    assert np.array_equal(joined.read(crop, prior, "hard"), mean > 0.5)
    with pytest.raises(ConfigError, match="at least one"):
        OutlineNets([])
    with pytest.raises(ConfigError, match="mask mode 'fuzzy' is unknown"):
        joined.read(crop, prior, "fuzzy")


def test_the_template_estimator_fits_its_kept_poses_with_an_outline_network(outline_run, tmp_path, monkeypatch):
    from simtest.estimators.templates import TemplateEstimator
    from simtest.estimators.templates.render import ObjectRenderer
    from simtest.estimators.templates.views import view_rotation

    monkeypatch.setenv("SIMTEST_CACHE", str(tmp_path))
    objects = load_object_set("builtin-small")
    obj = objects.by_name("mug_0")
    R, t = view_rotation([0.4, -0.6, 0.7]), np.array([0.05, -0.03, 0.65])
    with ObjectRenderer(obj, K, 640, 480) as renderer:
        rgb, mask = renderer.render(R, t)
    obs = Observation(rgb=rgb, depth=None, K=K, width=640, height=480, objects=objects,
                      target_obj_ids=(obj.obj_id,), masks=(mask,))
    plain = TemplateEstimator(detect="gt", views=60, refine="none", outline="none")
    fitted = TemplateEstimator(detect="gt", views=60, refine="none", outline=str(outline_run.model_path),
                               outline_max_scale=0.05, outline_deg=0.0)
    (a,), (b,) = plain.estimate(obs), fitted.estimate(obs)
    assert plain.outline is None and "outline" not in a.info
    assert b.info["outline"]["scale"] == pytest.approx(b.t[2] / a.t[2])
    assert abs(b.t[2] / a.t[2] - 1.0) <= 0.06 and np.allclose(a.R, b.R, atol=1e-12)
    with pytest.raises(ConfigError, match="outline_max_scale"):
        TemplateEstimator(outline_max_scale=1.5)
    with pytest.raises(ConfigError, match="outline_deg"):
        TemplateEstimator(outline_deg=-1.0)
    with pytest.raises(ConfigError, match="outline_mask 'fuzzy' is unknown; allowed: hard, soft, soft\\+flip"):
        TemplateEstimator(outline_mask="fuzzy")
    soft = TemplateEstimator(detect="gt", views=60, refine="none", outline=str(outline_run.model_path),
                             outline_max_scale=0.05, outline_deg=0.0, outline_mask="soft+flip")
    (c,) = soft.estimate(obs)
    assert abs(c.t[2] / a.t[2] - 1.0) <= 0.06 and set(c.info["outline"]) == set(b.info["outline"])


def test_without_the_image_skip_the_last_stage_reads_no_pixels_and_old_checkpoints_keep_it():
    """``image_skip=False`` drops the crop's pixels from the last decoder stage, which then reads the upsampled
    decoder and the prior only; a network record without the field (checkpoints made before it) keeps the
    skip."""
    from simtest.estimators.templates.mask_model import MaskNet, MaskNetConfig

    assert MaskNetConfig.from_dict({"crop_size": 64, "widths": [8, 8, 8, 8, 8]}).image_skip is True
    cfg = MaskNetConfig(crop_size=64, widths=(8, 8, 8, 8, 8), image_skip=False)
    assert MaskNetConfig.from_dict(cfg.to_dict()) == cfg
    x = torch.rand(1, 4, 64, 64, generator=torch.Generator().manual_seed(1))
    x[:, 3] = (x[:, 3] > 0.5).float()
    for skip in (True, False):
        net = MaskNet(MaskNetConfig(crop_size=64, widths=(8, 8, 8, 8, 8), image_skip=skip))
        net.init_weights(torch.Generator().manual_seed(0))
        seen = []
        net.d1.register_forward_hook(lambda mod, inp, out: seen.append(inp[0]))
        with torch.no_grad():
            assert net.eval()(x).shape == (1, 1, 64, 64)
        (inp,) = seen
        assert inp.shape[1] == 8 + (3 if skip else 0) + 1 and torch.equal(inp[:, -1], x[:, 3])
        assert torch.equal(inp[:, 8:11], x[:, :3]) is skip
    with pytest.raises(ConfigError):
        OutlineTrainConfig(data="x", out="y", crop_size=100, image_skip=False)


def test_the_mask_is_read_hard_soft_or_soft_with_its_mirror_image(outline_run):
    """``soft`` is the network's probability (its pixels above 0.5 are the hard mask), ``soft+flip`` the mean of
    the crop's and of its mirror image's probabilities (mirrored back: for a mirror-symmetric crop and prior the
    mask is mirror-symmetric); the fit takes each mode and refuses an unknown one by name."""
    net = OutlineNet(outline_run.model_path.with_suffix(".onnx"))
    rng = np.random.default_rng(2)
    crop = rng.integers(0, 255, (64, 64, 3), dtype=np.uint8)
    prior = np.zeros((64, 64), bool)
    prior[16:48, 20:40] = True
    hard, soft = net.read(crop, prior, "hard"), net.read(crop, prior, "soft")
    assert hard.dtype == bool and soft.dtype == np.float64 and 0.0 <= soft.min() and soft.max() <= 1.0
    assert np.array_equal(soft > 0.5, hard)
    mirror = net.probability(np.ascontiguousarray(crop[:, ::-1]), np.ascontiguousarray(prior[:, ::-1]))[:, ::-1]
    assert np.allclose(net.read(crop, prior, "soft+flip"), 0.5 * (soft + mirror))
    sym = np.concatenate([crop[:, :32], crop[:, :32][:, ::-1]], 1)
    sym_prior = np.concatenate([prior[:, :32], prior[:, :32][:, ::-1]], 1)
    both = net.read(sym, sym_prior, "soft+flip")
    assert np.allclose(both, both[:, ::-1], atol=1e-6)
    with pytest.raises(ConfigError, match="allowed: hard, soft, soft\\+flip"):
        net.read(crop, prior, "fuzzy")

    from simtest.estimators.templates.render import ObjectRenderer
    from simtest.estimators.templates.views import view_rotation

    obj = load_object_set("builtin-small").by_name("mug_0")
    R, t = view_rotation([0.4, -0.6, 0.7]), np.array([0.05, -0.03, 0.65])
    with ObjectRenderer(obj, K, 640, 480) as renderer:
        rgb, _ = renderer.render(R, t)
    for mode in ("soft", "soft+flip"):
        fit = outline_fit(net, obj, rgb, K, R, t, max_scale=0.1, step_deg=0.0, mask_mode=mode)
        assert abs(fit.scale - 1.0) <= 0.11 and np.allclose(fit.R, R, atol=1e-12)
    with pytest.raises(ConfigError, match="mask_mode 'fuzzy'"):
        outline_fit(net, obj, rgb, K, R, t, mask_mode="fuzzy")


def test_a_temperature_flattens_the_soft_masks_and_leaves_the_hard_one(outline_run):
    """At temperature T the probability is ``sigmoid(logit / T)`` (flatter for T > 1, the same pixels above 0.5),
    in both soft modes; the hard mask does not change; a temperature that is not a positive number is refused,
    by the network, the fit and both estimators, naming the value."""
    from scipy.special import expit

    from simtest.estimators.keypoints.crop_infer import CropKeypointEstimator
    from simtest.estimators.templates import TemplateEstimator

    net = OutlineNet(outline_run.model_path.with_suffix(".onnx"))
    rng = np.random.default_rng(3)
    crop = rng.integers(0, 255, (64, 64, 3), dtype=np.uint8)
    prior = np.zeros((64, 64), bool)
    prior[12:50, 18:44] = True
    logits = net.logits(crop, prior).astype(np.float64)
    warm = net.read(crop, prior, "soft", temperature=2.0)
    assert np.allclose(warm, expit(logits / 2.0), atol=1e-12)
    assert np.array_equal(warm > 0.5, net.read(crop, prior, "soft") > 0.5)
    assert np.all(np.abs(warm - 0.5) <= np.abs(net.read(crop, prior, "soft") - 0.5) + 1e-12)
    mirror = expit(net.logits(np.ascontiguousarray(crop[:, ::-1]), np.ascontiguousarray(prior[:, ::-1]))[:, ::-1]
                   / 2.0)
    assert np.allclose(net.read(crop, prior, "soft+flip", 2.0), 0.5 * (warm + mirror), atol=1e-12)
    assert np.array_equal(net.read(crop, prior, "hard", 4.0), net.read(crop, prior, "hard"))
    for bad in (0.0, -1.0, float("nan"), float("inf"), "warm"):
        with pytest.raises(ConfigError, match="outline network: temperature must be a positive number, got"):
            net.probability(crop, prior, temperature=bad)
    obj = load_object_set("builtin-small").by_name("mug_0")
    with pytest.raises(ConfigError, match="temperature must be a positive number, got 0"):
        outline_fit(net, obj, np.zeros((480, 640, 3), np.uint8), K, np.eye(3), np.array([0, 0, 0.6]),
                    mask_mode="soft", temperature=0)
    with pytest.raises(ConfigError, match="templates: outline_temperature must be a positive number, got -2"):
        TemplateEstimator(outline_temperature=-2)
    with pytest.raises(ConfigError, match="keypoints: outline_temperature must be a positive number, got 'x'"):
        CropKeypointEstimator(outline_temperature="x")
