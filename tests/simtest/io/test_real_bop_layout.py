"""A BOP test set as the benchmark distributes it is read as it is: its only split, no ``depth/`` or ``mask*/``,
rotations rounded to ~1e-2, a ``test_targets_bop19.json`` choosing images and objects. Each test makes such a
set from a dataset written by the real generation pipeline (no real photographs in the repository); the last
test reads the real LM-O excerpt in ``../shared/real/lmo`` when it is present."""

from __future__ import annotations

import json
import logging
import os
import shutil
from pathlib import Path

import numpy as np
import pytest

from simtest.cli import main
from simtest.corrupt import CorruptionSpec, corrupt_dataset
from simtest.errors import ConfigError, DatasetError
from simtest.evaluation.run import evaluate
from simtest.io import bop
from simtest.io.bop_checks import ROT_REPAIR_TOL, ROT_TOL, nearest_rotations

#: The real LM-O excerpt: $SIMTEST_REAL_LMO, else ../shared/real/lmo beside the repository.
REAL_LMO = Path(os.environ.get("SIMTEST_REAL_LMO") or Path(__file__).resolve().parents[4] / "shared" / "real" / "lmo")


def _deviation(R9) -> float:
    M = np.asarray(R9, np.float64).reshape(3, 3)
    return float(np.abs(M.T @ M - np.eye(3)).max())


def _perturb(R9, rng: np.random.Generator, size: float) -> list[float]:
    """``R9`` stretched along random axes by ``e`` in [size / 4, size]: ``max |R^T R - I|`` is about ``2 e``
    (det still > 0), as rounded annotations are off."""
    e = rng.uniform(size / 4, size)
    Q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    S = Q @ np.diag([e, -e, rng.uniform(-e, e)]) @ Q.T
    return (np.asarray(R9, np.float64).reshape(3, 3) @ (np.eye(3) + S)).reshape(-1).tolist()


def as_distributed(src: Path, dst: Path, rounding: float | None = 0.004, seed: int = 0) -> dict:
    """A copy of generated dataset ``src`` laid out as a real BOP test set: split ``test``, no ``depth/``,
    ``mask/`` or ``mask_visib/``, no manifest; with ``rounding``, every other ground-truth rotation perturbed by
    up to that much (as rounded annotations). Returns ``{"perturbed": count, "worst": max deviation}``."""
    shutil.copytree(src, dst)
    (dst / "train_pbr").rename(dst / "test")
    (dst / "manifest.json").unlink()
    for scene in bop.scene_dirs(dst / "test"):
        for sub in ("depth", "mask", "mask_visib"):
            shutil.rmtree(scene / sub)
    stats = {"perturbed": 0, "worst": 0.0}
    if rounding is None:
        return stats
    rng = np.random.default_rng(seed)
    for scene in bop.scene_dirs(dst / "test"):
        path = scene / "scene_gt.json"
        gt = json.loads(path.read_text())
        k = 0
        for insts in gt.values():
            for g in insts:
                k += 1
                if k % 2:
                    g["cam_R_m2c"] = _perturb(g["cam_R_m2c"], rng, rounding)
                    dev = _deviation(g["cam_R_m2c"])
                    assert ROT_TOL < dev <= ROT_REPAIR_TOL  # in the band that is repaired
                    stats["perturbed"] += 1
                    stats["worst"] = max(stats["worst"], dev)
        path.write_text(json.dumps(gt))
    return stats


@pytest.fixture(scope="module")
def distributed(small_dataset, tmp_path_factory):
    root = tmp_path_factory.mktemp("real") / "lmo_like"
    stats = as_distributed(small_dataset, root)
    return root, stats


class RgbOnly:
    """A plug-in that declares it reads no depth, and checks it is given none."""

    needs_depth = False

    def __init__(self) -> None:
        self.depths: list = []

    def estimate(self, observation):
        self.depths.append(observation.depth)
        assert observation.rgb.shape[2] == 3
        return []


# ---------------------------------------------------------------------------------------------------------
def test_nearest_rotations_projects_and_keeps_rotations():
    rng = np.random.default_rng(1)
    Q, _ = np.linalg.qr(rng.normal(size=(5, 3, 3)))
    Q[np.linalg.det(Q) < 0] *= -1
    assert np.allclose(nearest_rotations(Q), Q, atol=1e-12)
    noisy = Q + rng.uniform(-5e-3, 5e-3, Q.shape)
    R = nearest_rotations(noisy)
    assert np.allclose(np.einsum("nji,njk->nik", R, R), np.eye(3), atol=1e-12)
    assert np.allclose(np.linalg.det(R), 1.0)
    assert np.abs(R - Q).max() < 1e-2


def test_distributed_set_is_read_with_its_only_split_and_repairs_counted(distributed, small_dataset, caplog):
    root, stats = distributed
    caplog.set_level(logging.INFO, logger="simtest")
    report = evaluate(root, "oracle", progress=False)  # no split, no depth, no masks, rounded rotations
    assert report.settings["split"] == "test"
    assert report.overall["add_s_or_add_01d"] == 1.0
    orig = evaluate(small_dataset, "oracle", progress=False, vsd=False)
    assert report.overall["num_targets"] == orig.overall["num_targets"] > 0
    warnings = [r for r in caplog.records if r.levelno == logging.WARNING and "rotation" in r.getMessage()]
    assert len(warnings) == 1  # one summary for the whole dataset
    msg = warnings[0].getMessage()
    assert f"{stats['perturbed']} ground-truth rotations" in msg and f"{stats['worst']:.3g}" in msg
    notes = report.settings["data_notes"]
    assert any("VSD skipped" in n for n in notes) and any("no depth/" in n for n in notes)
    # the repaired rotations are rotations, and near what was written
    frames = bop.read_scene(root / "test" / "000000")
    for f in frames.values():
        for g in f["gt"]:
            assert _deviation(g.T_cam_obj.R) < 1e-9 and np.linalg.det(g.T_cam_obj.R) > 0


def test_rgb_only_estimator_reads_the_distributed_set_as_the_original(distributed, small_dataset, tmp_path):
    """The shipped RGB-only keypoint network gives the same estimates on the set without depth and masks as on
    the dataset it came from (same pixels, same camera): nothing it reads went missing."""
    root, _ = distributed
    stripped = evaluate(root, "keypoints", progress=False, out_dir=tmp_path / "a")
    full = evaluate(small_dataset, "keypoints", progress=False, vsd=False, out_dir=tmp_path / "b")
    key = [(r.scene_id, r.im_id, r.obj_id) for r in full.estimates]
    assert key and key == [(r.scene_id, r.im_id, r.obj_id) for r in stripped.estimates]
    for a, b in zip(stripped.estimates, full.estimates):
        assert np.allclose(a.R, b.R) and np.allclose(a.t, b.t)
    assert not stripped.failures
    est = RgbOnly()
    evaluate(root, est, progress=False)
    assert est.depths and all(d is None for d in est.depths)
    assert "VSD skipped" in (tmp_path / "a" / "metrics.md").read_text()


def test_gross_rotation_error_is_refused_with_file_image_and_instance(distributed, tmp_path):
    root, _ = distributed
    bad = tmp_path / "bad"
    shutil.copytree(root, bad)
    path = bad / "test" / "000001" / "scene_gt.json"
    gt = json.loads(path.read_text())
    gt["2"][1]["cam_R_m2c"] = (np.eye(3) + np.diag([0.05, 0.0, 0.0])).reshape(-1).tolist()
    path.write_text(json.dumps(gt))
    est = RgbOnly()
    with pytest.raises(DatasetError, match=r"test/000001/scene_gt\.json: image 2, instance 1: cam_R_m2c is .*not "
                                           r"a rotation \(max \|R\^T R - I\| = 0\.103.*up to 0\.01 is repaired"):
        evaluate(bad, est, progress=False)
    assert est.depths == []


def test_estimators_that_read_what_is_missing_are_refused_before_running(distributed, tmp_path):
    root, _ = distributed
    with pytest.raises(DatasetError, match=r"has no depth/ .* estimator 'icp' reads depth"):
        evaluate(root, "icp", progress=False)

    class NeedsMasks(RgbOnly):
        needs_gt_masks = True

    with pytest.raises(DatasetError, match=r"has no mask_visib/ .* ground-truth visible masks"):
        evaluate(root, NeedsMasks(), progress=False)
    assert not (tmp_path / "out").exists()


def test_a_network_for_other_objects_is_refused_before_the_run(distributed, tmp_path):
    """The shipped keypoint network knows builtin-small's objects: on a set with another object (id 1 renamed
    31 here) the run stops before any image with the reason, instead of failing image after image."""
    root, _ = distributed
    other = tmp_path / "other"
    shutil.copytree(root, other)
    (other / "models" / "obj_000001.ply").rename(other / "models" / "obj_000031.ply")
    info = json.loads((other / "models" / "models_info.json").read_text())
    info["31"] = info.pop("1")
    (other / "models" / "models_info.json").write_text(json.dumps(info))
    with pytest.raises(ConfigError, match=r"trained for objects .* object ids differ"):
        evaluate(other, "keypoints", progress=False, out_dir=tmp_path / "run")
    assert not (tmp_path / "run" / "results.csv").exists()


def test_several_splits_need_a_choice(distributed, tmp_path):
    root, _ = distributed
    two = tmp_path / "two"
    shutil.copytree(root, two)
    shutil.copytree(two / "test", two / "val")
    with pytest.raises(DatasetError, match=r"several splits \(test, val\); choose one with --split"):
        evaluate(two, "oracle", progress=False)
    assert evaluate(two, "oracle", split="val", progress=False).settings["split"] == "val"


def test_targets_file_chooses_images_and_objects(distributed, tmp_path):
    """As the BOP toolkit: only listed images are evaluated; a target is a listed object's instance visible
    from 10 %."""
    root, _ = distributed
    ds = tmp_path / "targets"
    shutil.copytree(root, ds)
    frames = bop.read_scene(ds / "test" / "000000")
    visible = {im: sorted({g.obj_id for g in f["gt"] if g.visib_fract >= 0.1}) for im, f in frames.items()}
    im_a, im_b = sorted(visible)[:2]
    dropped = visible[im_b][0]
    listed = [{"im_id": im_a, "inst_count": 1, "obj_id": o, "scene_id": 0} for o in visible[im_a]] + \
             [{"im_id": im_b, "inst_count": 1, "obj_id": o, "scene_id": 0} for o in visible[im_b][1:]]
    (ds / "test_targets_bop19.json").write_text(json.dumps(listed))
    report = evaluate(ds, "oracle", progress=False)
    assert report.num_images == 2
    want = sum(1 for im in (im_a, im_b) for g in frames[im]["gt"]
               if g.visib_fract >= 0.1 and not (im == im_b and g.obj_id == dropped))
    assert report.overall["num_targets"] == want
    assert not any(r["im_id"] == im_b and r["obj_id"] == dropped for r in report.errors)
    assert any("images chosen by test_targets_bop19.json" in n for n in report.settings["data_notes"])
    # a target file naming images this split lacks is not used (with a note)
    (ds / "test_targets_bop19.json").write_text(json.dumps([{"im_id": 999, "inst_count": 1, "obj_id": 1,
                                                              "scene_id": 0}]))
    report = evaluate(ds, "oracle", progress=False)
    assert report.num_images == sum(len(bop.read_scene(d)) for d in bop.scene_dirs(ds / "test"))
    assert any("names images the split lacks" in n for n in report.settings["data_notes"])


def test_show_and_corrupt_take_the_distributed_set(distributed, tmp_path, capsys):
    root, _ = distributed
    assert main(["show", str(root), "--out", str(tmp_path / "show"), "--images", "1"]) == 0
    assert len(list((tmp_path / "show").glob("*.png"))) == 1
    out = tmp_path / "fog"
    corrupt_dataset(root, out, CorruptionSpec(weather="fog", severity=2), seed=0, progress=False)
    assert evaluate(out, "oracle", progress=False).overall["add_s_or_add_01d"] == 1.0
    with pytest.raises(DatasetError, match=r"has no depth/ folder: depth noise"):
        corrupt_dataset(root, tmp_path / "noisy", CorruptionSpec(depth_noise="realsense-d435"), seed=0,
                        progress=False)
    assert not (tmp_path / "noisy").exists()


@pytest.mark.skipif(not REAL_LMO.is_dir(), reason=f"the real LM-O excerpt is not at {REAL_LMO} (see shared/real)")
def test_real_lmo_excerpt_is_scored_as_distributed(tmp_path):
    report = evaluate(REAL_LMO, "oracle", progress=False, out_dir=tmp_path / "run")
    assert report.num_images == 100
    # 737 entries in test_targets_bop19.json; 3 of them have visib_fract < 0.1 in scene_gt_info.json, which the
    # BOP toolkit does not count
    assert report.overall["num_targets"] == 734
    assert report.overall["add_s_or_add_01d"] == 1.0 and report.overall["ar"] == 1.0
