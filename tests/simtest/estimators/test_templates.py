"""The template estimator on real renders of built-in objects: crops through the virtual camera, the bank cache,
and poses of clean renders recovered from templates and frozen ImageNet features."""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict

import cv2
import numpy as np
import pytest

from simtest.errors import ConfigError
from simtest.estimators.base import Observation
from simtest.estimators.templates import TemplateEstimator
from simtest.estimators.templates.bank import (FORMAT, RENDER_SIZE, BankSettings, _appearance_hash, bank_path,
                                               load_or_build, render_intrinsics, template_image)
from simtest.estimators.templates.crops import region_crop, window_centre
from simtest.estimators.templates.framing import framing_search
from simtest.estimators.templates.match import template_pose
from simtest.estimators.templates.encoder import FeatureEncoder
from simtest.estimators.templates.export import default_encoder
from simtest.estimators.templates.render import ObjectRenderer
from simtest.estimators.templates.views import inplane_rotation, sphere_directions, view_rotation
from simtest.objects import load_object_set

K = np.array([[572.4, 0.0, 325.3], [0.0, 573.6, 242.0], [0.0, 0.0, 1.0]])
W, H = 640, 480


@pytest.fixture(scope="module")
def objects():
    return load_object_set("builtin-small")


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    return tmp_path_factory.mktemp("templates")


def _angle_deg(Ra: np.ndarray, Rb: np.ndarray) -> float:
    return float(np.degrees(np.arccos(np.clip((np.trace(Ra.T @ Rb) - 1.0) / 2.0, -1.0, 1.0))))


def test_views_cover_the_upper_sphere():
    d = sphere_directions(400, min_elevation_deg=0.0)
    assert 190 <= len(d) <= 210 and np.allclose(np.linalg.norm(d, axis=1), 1.0) and (d[:, 2] >= 0).all()
    R = view_rotation(d[7])
    assert np.allclose(R @ R.T, np.eye(3)) and np.isclose(np.linalg.det(R), 1.0)
    assert np.allclose(R @ d[7], [0.0, 0.0, -1.0])  # the camera looks at the model origin
    with pytest.raises(ConfigError, match="count"):
        sphere_directions(1)


def test_region_crop_is_a_pinhole_view_of_the_same_pose(objects):
    """A pose in the real camera seen through the crop's camera (``R_virt``, ``K_crop``) projects where the warp
    puts the full image's pixel, and the rendered object lands inside the crop."""
    obj = objects.by_name("banana_0")
    R, t = inplane_rotation(0.4) @ view_rotation([0.3, -0.5, 0.8]), np.array([0.15, -0.08, 0.7])
    with ObjectRenderer(obj, K, W, H) as renderer:
        rgb, mask = renderer.render(R, t)
    crop = region_crop(rgb, mask, K, 128, 1.2, inplane_rad=0.3)
    full = K @ t
    in_crop = crop.K @ (crop.R_virt @ t)
    Hm = crop.K @ crop.R_virt @ np.linalg.inv(K)
    warped = cv2.perspectiveTransform((full[:2] / full[2]).reshape(1, 1, 2), Hm).ravel()
    assert np.allclose(in_crop[:2] / in_crop[2], warped, atol=1e-6)
    rows, cols = np.nonzero(crop.mask)
    span = max(np.ptp(rows), np.ptp(cols)) + 1  # the box's longer side is 1 / margin of the crop
    assert 128 / 1.2 - 3 <= span <= 128 / 1.2 + 3, span
    assert not (crop.mask[0].any() or crop.mask[-1].any() or crop.mask[:, 0].any() or crop.mask[:, -1].any())
    with pytest.raises(ConfigError, match="non-empty mask"):
        region_crop(rgb, np.zeros_like(mask), K, 128)


def test_bank_is_cached_and_reused(objects, cache):
    obj = objects.by_name("mug_0")
    settings = BankSettings(views=60, min_elevation_deg=0.0)
    enc = FeatureEncoder(settings.stride, default_encoder() if default_encoder().is_file() else None)
    path = bank_path(obj, settings, cache)
    assert not path.exists()
    first = load_or_build(obj, settings, enc, cache)
    stamp = path.stat().st_mtime_ns
    again = load_or_build(obj, settings, enc, cache)
    assert path.stat().st_mtime_ns == stamp  # read, not rebuilt
    assert np.array_equal(first.feats, again.feats) and np.allclose(first.R, again.R)
    assert first.feats.shape == (len(first), 40, 16, 16) and first.masks.max() > 0.9
    assert bank_path(obj, BankSettings(views=61, min_elevation_deg=0.0), cache) != path


def test_template_background_is_a_setting_of_its_own(objects, cache):
    """A grey background behind the template is drawn where the object is not (the object's own pixels are the
    same render), is part of the bank's cache key, and the default black keeps the key banks had before."""
    obj = objects.by_name("mug_0")
    black, grey = BankSettings(views=60), BankSettings(views=60, background=128)
    old = {k: v for k, v in asdict(black).items() if k != "background"}
    key = json.dumps({"format": FORMAT, "mesh": obj.mesh_hash, "appearance": _appearance_hash(obj), **old},
                     sort_keys=True)
    assert bank_path(obj, black, cache).name == f"{obj.name}_{hashlib.sha1(key.encode()).hexdigest()[:20]}.npz"
    assert bank_path(obj, grey, cache) != bank_path(obj, black, cache)
    R = view_rotation([0.3, -0.5, 0.8])
    with ObjectRenderer(obj, render_intrinsics(obj, black), RENDER_SIZE, RENDER_SIZE) as renderer:
        (b, mb), (g, mg) = template_image(renderer, R, black), template_image(renderer, R, grey)
    assert np.array_equal(mb, mg) and mb.any() and not mb.all()
    assert np.array_equal(b[mb], g[mb]) and b[~mb].max() == 0 and np.all(g[~mg] == 128)
    with pytest.raises(ConfigError, match="background"):
        BankSettings(background=300).check()


@pytest.mark.parametrize("name", ["banana_0", "mug_0"])
def test_clean_render_pose_from_templates(objects, cache, monkeypatch, name):
    """A clean render at a pose between the bank's views: rotation within 15 degrees, the centre
    within 6 pixels, the depth within 10 % (the views lie about 8 degrees apart)."""
    monkeypatch.setenv("SIMTEST_CACHE", str(cache))
    obj = objects.by_name(name)
    est = TemplateEstimator(detect="gt", views=600, min_elevation_deg=0.0)
    rng = np.random.default_rng(3)
    with ObjectRenderer(obj, K, W, H) as renderer:
        for _ in range(2):
            d = rng.normal(size=3)
            d[2] = abs(d[2]) + 0.3
            R = inplane_rotation(np.radians(rng.uniform(-25, 25))) @ view_rotation(d)
            t = np.array([rng.uniform(-0.15, 0.15), rng.uniform(-0.1, 0.1), rng.uniform(0.5, 0.8)])
            rgb, mask = renderer.render(R, t)
            obs = Observation(rgb=rgb, depth=None, K=K, width=W, height=H, objects=objects,
                              target_obj_ids=(obj.obj_id,), masks=(mask,))
            (e,) = est.estimate(obs)
            assert _angle_deg(e.R, R) < 15.0, (name, _angle_deg(e.R, R), e.info)
            px = np.linalg.norm((K @ e.t)[:2] / e.t[2] - (K @ t)[:2] / t[2])
            assert px < 6.0 and abs(e.t[2] / t[2] - 1.0) < 0.1, (name, px, e.t, t)


def test_bad_options_name_the_value():
    with pytest.raises(ConfigError, match="'depth'"):
        TemplateEstimator(detect="depth")
    with pytest.raises(ConfigError, match="multiple of 32"):
        TemplateEstimator(size=100)


def test_registered_by_name():
    from simtest.estimators.base import estimator_label
    from simtest.estimators.registry import load_estimator

    est = load_estimator("templates", detect="gt", views=60)
    assert isinstance(est, TemplateEstimator) and est.needs_gt_masks and not est.needs_depth
    assert estimator_label("templates", est) == "templates (GT masks)"


def test_detector_candidates_keep_the_best_match_per_expected_instance(small_dataset, cache, monkeypatch):
    """``candidates=3`` with the shipped builtin-small detector on generated frames: every candidate region of
    an object is posed, and as many as the image has instances of it are kept, the best template matches
    (``select=match``) or the detector's first regions (``select=prob``)."""
    from collections import Counter

    from simtest.evaluation.images import observation
    from simtest.io.dataset import image_size, select_images
    from simtest.objects.loaders import load_dataset_objects

    monkeypatch.setenv("SIMTEST_CACHE", str(cache))
    objects = load_dataset_objects(small_dataset)
    width, height = image_size(small_dataset)
    seen = 0
    for select in ("match", "prob"):
        est = TemplateEstimator(detect="rgb", views=60, min_elevation_deg=0.0, candidates=3, select=select)
        for ref in select_images(small_dataset, None, None, 2, objects.ids):
            obs, _ = observation(ref, objects, "gt-masks", width, height, False)
            found = est.estimate(obs)
            wanted = Counter(obs.target_obj_ids)
            assert all(n <= wanted[o] for o, n in Counter(e.obj_id for e in found).items())
            cands = est.last_candidates
            assert sum(c["kept"] for c in cands) == len(found)
            for oid in {c["obj_id"] for c in cands}:
                mine = [c for c in cands if c["obj_id"] == oid]
                kept = [c for c in mine if c["kept"]]
                assert len(mine) <= 3 * wanted[oid] and len(kept) == min(len(mine), wanted[oid])
                if select == "prob":
                    assert sorted(c["rank"] for c in kept) == list(range(len(kept)))
                else:
                    dropped = [c["match"] for c in mine if not c["kept"]]
                    assert min(c["match"] for c in kept) >= max(dropped, default=-1.0)
            seen += len(cands)
    assert seen > 0
    with pytest.raises(ConfigError, match="unknown select 'area'"):
        TemplateEstimator(select="area")
    with pytest.raises(ConfigError, match="candidates >= 1, got 0"):
        TemplateEstimator(candidates=0)


def test_pooled_detectors_pose_a_shared_region_once(small_dataset, cache, monkeypatch):
    """``detector=A+B`` pools the candidate regions of both detectors; the same detector twice gives exactly the
    regions of one (each region of B overlaps its copy in A at IoU 1 and is dropped)."""
    from simtest.estimators.segicp.infer import FORMAT
    from simtest.estimators.shipped import choose
    from simtest.evaluation.images import observation
    from simtest.io.dataset import image_size, select_images
    from simtest.objects.loaders import load_dataset_objects

    monkeypatch.setenv("SIMTEST_CACHE", str(cache))
    objects = load_dataset_objects(small_dataset)
    width, height = image_size(small_dataset)
    path = str(choose("keypoints_detector", FORMAT, objects, what="test", subset=True).path)
    one = TemplateEstimator(detect="rgb", detector=path, candidates=3)
    two = TemplateEstimator(detect="rgb", detector=f"{path}+{path}", candidates=3)
    counted = 0
    for ref in select_images(small_dataset, None, None, 2, objects.ids):
        obs, _ = observation(ref, objects, "gt-masks", width, height, False)
        a, b = one.regions(obs), two.regions(obs)
        assert len(two.more_segmenters) == 1
        assert [(r[1], r[3]) for r in a] == [(r[1], r[3]) for r in b]
        assert all(np.array_equal(ra[2], rb[2]) for ra, rb in zip(a, b))
        counted += len(a)
    assert counted > 0


def test_extra_regions_add_only_what_the_class_map_misses(small_dataset, cache, monkeypatch):
    """``region_extra``: the class map's regions come first, unchanged; then the regions of pixels whose class
    probability exceeds it, each overlapping none of its object's earlier regions at IoU > EXTRA_REGION_IOU and
    lying wholly above it (eroded); a value outside [0, 1) is refused by name."""
    from simtest.estimators.segicp.infer import FORMAT
    from simtest.estimators.shipped import choose
    from simtest.estimators.templates.estimator import EXTRA_REGION_IOU, _iou
    from simtest.evaluation.images import observation
    from simtest.io.dataset import image_size, select_images
    from simtest.objects.loaders import load_dataset_objects

    monkeypatch.setenv("SIMTEST_CACHE", str(cache))
    objects = load_dataset_objects(small_dataset)
    width, height = image_size(small_dataset)
    path = str(choose("keypoints_detector", FORMAT, objects, what="test", subset=True).path)
    plain = TemplateEstimator(detect="rgb", detector=path, candidates=3)
    extra = TemplateEstimator(detect="rgb", detector=path, candidates=3, region_extra=0.05)
    added = 0
    for ref in select_images(small_dataset, None, None, 3, objects.ids):
        obs, _ = observation(ref, objects, "gt-masks", width, height, False)
        a, b = plain.regions(obs), extra.regions(obs)
        assert [(r[1], r[3]) for r in b[:len(a)]] == [(r[1], r[3]) for r in a]
        assert all(np.array_equal(ra[2], rb[2]) for ra, rb in zip(a, b))
        prob = extra.segmenter.probabilities(obs.rgb, np.zeros(obs.rgb.shape[:2], np.float32), np.asarray(obs.K))
        for n, (_, oid, mask, p) in enumerate(b[len(a):], start=len(a)):
            c = extra.segmenter.class_ids.index(oid) + 1
            assert mask.any() and float(prob[c][mask].min()) > 0.05 and 0.05 < p <= 1.0
            assert all(_iou(r[2], mask) <= EXTRA_REGION_IOU for r in b[:n] if r[1] == oid)
            added += 1
    assert added > 0
    with pytest.raises(ConfigError, match=r"region_extra must be a class probability in \[0, 1\), got 1.0"):
        TemplateEstimator(region_extra=1.0)


def _loose_region(objects) -> tuple[Observation, np.ndarray]:
    """A mug rendered at 0.65 m, given as a region far larger than it and off its centre (a coarse detector's):
    the observation and the true translation (metres)."""
    obj = objects.by_name("mug_0")
    R, t = inplane_rotation(np.radians(10.0)) @ view_rotation([0.4, -0.6, 0.7]), np.array([0.05, -0.03, 0.65])
    with ObjectRenderer(obj, K, W, H) as renderer:
        rgb, mask = renderer.render(R, t)
    loose = cv2.dilate(np.roll(mask, (14, -10), axis=(0, 1)).astype(np.uint8), np.ones((41, 41), np.uint8)) > 0
    return Observation(rgb=rgb, depth=None, K=K, width=W, height=H, objects=objects,
                       target_obj_ids=(obj.obj_id,), masks=(loose,)), t


def test_framing_search_frees_the_pose_from_a_loose_region(objects, cache, monkeypatch):
    """A region far larger than the object and off its centre (a coarse detector's) puts the matched template's
    pose off in depth; the framing search moves and scales the window onto the object: the depth within 8 %
    and the centre within 6 pixels, closer than the region's own framing."""
    monkeypatch.setenv("SIMTEST_CACHE", str(cache))
    est = TemplateEstimator(detect="gt", views=600, min_elevation_deg=0.0, refine="none")
    obs, t = _loose_region(objects)
    (plain,) = est.estimate(obs)
    est.framing = True
    (framed,) = est.estimate(obs)
    assert framed.info["framing_crops"] > 7 and framed.info["match"] >= framed.info["match_region"]

    def errors(e):
        px = float(np.linalg.norm((K @ e.t)[:2] / e.t[2] - (K @ t)[:2] / t[2]))
        return px, abs(e.t[2] / t[2] - 1.0)

    (px_f, dz_f), (px_p, dz_p) = errors(framed), errors(plain)
    assert dz_f < 0.08 and px_f < 6.0 and dz_f < dz_p, (px_f, dz_f, px_p, dz_p)
    (again,) = est.estimate(obs)
    assert np.array_equal(again.t, framed.t) and np.array_equal(again.R, framed.R)  # deterministic


def test_polish_refines_the_framing_and_depth_scale_moves_along_the_ray(objects, cache, monkeypatch):
    """The last framing search against the final template alone (after the local search) starts where the
    first ended, so its match is at least as good and the depth stays close; ``depth_scale`` multiplies the matched translation exactly
    (the object keeps its pixel), and the rest of the pose is unchanged."""
    monkeypatch.setenv("SIMTEST_CACHE", str(cache))
    obs, t = _loose_region(objects)
    est = TemplateEstimator(detect="gt", views=600, min_elevation_deg=0.0, refine="none", framing=True,
                            local_deg=4.0, polish=0.02)
    (polished,) = est.estimate(obs)
    info = polished.info
    assert "match_local" in info  # a local template was found, so the polish searched against it
    # the polish starts from the final template's framing and only moves uphill
    assert info["polish_crops"] > 8 and info["match_polish"] >= info.get("match_local", info["match"])
    assert abs(polished.t[2] / t[2] - 1.0) < 0.08
    est.depth_scale = 0.98
    (scaled,) = est.estimate(obs)
    assert np.allclose(scaled.t, 0.98 * polished.t, rtol=1e-12, atol=0.0) and np.array_equal(scaled.R, polished.R)
    with pytest.raises(ConfigError, match="depth_scale"):
        TemplateEstimator(depth_scale=3.0)
    with pytest.raises(ConfigError, match="polish"):
        TemplateEstimator(polish=0.7)
    with pytest.raises(ConfigError, match="polish_min_shift"):
        TemplateEstimator(polish=0.02, polish_min_shift=0.0)
    # the local search stopped at 2 degrees instead of 1 renders fewer templates and matches no better
    est.depth_scale, est.polish = 1.0, 0.0
    (fine,) = est.estimate(obs)
    est.local_min_deg = 2.0
    (coarse,) = est.estimate(obs)
    assert 0 < coarse.info["local_renders"] < fine.info["local_renders"]
    assert coarse.info.get("match_local", coarse.info["match"]) <= fine.info.get("match_local", fine.info["match"])
    with pytest.raises(ConfigError, match="0 < local_min_deg <= local_deg .*got local_min_deg=0,"):
        TemplateEstimator(local_deg=4.0, local_min_deg=0)
    with pytest.raises(ConfigError, match="got local_min_deg=8, local_deg=4.0"):
        TemplateEstimator(local_deg=4.0, local_min_deg=8)


def test_silhouette_fit_runs_after_the_framing_search(objects, cache, monkeypatch):
    """The framing search's crop carries no region, so the silhouette fit looks at the searched framing through a
    crop that carries the region's mask: with the exact mask the fit runs, its outline agrees with the mask at
    least as well as the matched one, and the depth ends within 3 %."""
    monkeypatch.setenv("SIMTEST_CACHE", str(cache))
    obj = objects.by_name("mug_0")
    R, t = inplane_rotation(np.radians(10.0)) @ view_rotation([0.4, -0.6, 0.7]), np.array([0.05, -0.03, 0.65])
    with ObjectRenderer(obj, K, W, H) as renderer:
        rgb, mask = renderer.render(R, t)
    obs = Observation(rgb=rgb, depth=None, K=K, width=W, height=H, objects=objects,
                      target_obj_ids=(obj.obj_id,), masks=(mask,))
    est = TemplateEstimator(detect="gt", views=600, min_elevation_deg=0.0, refine="silhouette", framing=True)
    (e,) = est.estimate(obs)
    fit = e.info["silhouette"]
    assert fit["iou_before"] > 0.5 and fit["iou_after"] >= fit["iou_before"], fit
    assert abs(e.t[2] / t[2] - 1.0) < 0.03, (e.t, t)


def test_framing_starts_grow_a_window_out_of_a_partial_region(objects, cache, monkeypatch):
    """A region that holds only part of its object (the left third of the mug, as a detector's on a real frame)
    frames a window too small; started also from the window scaled 1.4 and 2 times, the search keeps the best
    match (never worse than the single start) and its depth error falls from 2.5 to 0.3 %. The single start is
    the plain search from the region's window, and bad factors are refused with the value named."""
    monkeypatch.setenv("SIMTEST_CACHE", str(cache))
    obj = objects.by_name("mug_0")
    R, t = inplane_rotation(np.radians(10.0)) @ view_rotation([0.4, -0.6, 0.7]), np.array([0.05, -0.03, 0.65])
    with ObjectRenderer(obj, K, W, H) as renderer:
        rgb, mask = renderer.render(R, t)
    cols = np.nonzero(mask.any(axis=0))[0]
    part = mask.copy()
    part[:, cols[0] + (cols[-1] - cols[0]) // 3:] = False
    obs = Observation(rgb=rgb, depth=None, K=K, width=W, height=H, objects=objects,
                      target_obj_ids=(obj.obj_id,), masks=(part,))
    est = TemplateEstimator(detect="gt", views=600, min_elevation_deg=0.0, refine="none", framing=True)
    (one,) = est.estimate(obs)
    # the single start (the default) is the plain search from the region's own window
    bank, weights = est.bank(obj)
    crops, _, _, a, _, _ = est.region_match(weights, rgb, part, K)
    fr = framing_search(rgb, K, window_centre(crops[a], K), crops[a].window[2], float(est.inplane[a]), est.encoder,
                        weights, est.settings.size)
    R_fr, t_fr = template_pose(bank, fr.template, fr.crop.K, fr.crop.R_virt)
    assert one.info["framing_start"] == 1.0 and one.info["match"] == fr.score
    assert np.array_equal(one.R, R_fr) and np.array_equal(one.t, t_fr)
    est.framing_starts = (1.0, 1.4, 2.0)
    (multi,) = est.estimate(obs)
    assert multi.info["match"] >= one.info["match"] and multi.info["framing_start"] in (1.0, 1.4, 2.0)
    assert multi.info["framing_crops"] > one.info["framing_crops"]
    dz_one, dz_multi = abs(one.t[2] / t[2] - 1.0), abs(multi.t[2] / t[2] - 1.0)
    assert dz_multi < 0.01 and dz_multi < 0.5 * dz_one, (dz_one, dz_multi, multi.info["framing_start"])  # 2.5 -> 0.3 %
    for bad in ((), (0.1,), ("2",), (1.0, 9.0), True):
        with pytest.raises(ConfigError, match="framing_starts"):
            TemplateEstimator(framing_starts=bad)
    assert TemplateEstimator(framing_starts=1.5).framing_starts == (1.5,)


def test_prepare_reads_or_builds_every_bank_before_the_first_image(objects, tmp_path, monkeypatch):
    """``prepare`` (called by the evaluation outside the per-image time limit) loads the shipped detector and
    fills the cache with the bank of every object it looks for, so the first image only reads them; with
    ground-truth masks the targets are unknown before the images and nothing is built."""
    from simtest.estimators.templates.bank import bank_path

    monkeypatch.setenv("SIMTEST_CACHE", str(tmp_path))
    est = TemplateEstimator(detect="rgb", views=60, refine="none", outline="none")
    paths = [bank_path(objects.get(i), est.settings) for i in objects.ids]
    assert not any(p.exists() for p in paths)
    gt = TemplateEstimator(detect="gt", views=60, refine="none", outline="none")
    gt.prepare(objects)
    assert not gt.banks and not any(p.exists() for p in paths)
    est.prepare(objects)
    assert est.segmenter is not None and set(est.segmenter.class_ids) == {int(i) for i in objects.ids}
    assert all(p.is_file() for p in paths) and sorted(est.banks) == sorted(int(i) for i in objects.ids)
    assert est.time_limit_s == 900.0
