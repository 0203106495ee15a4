"""Baseline estimators on real generated data: oracle, icp, umeyama; plug-in loading with options."""

from __future__ import annotations

import sys
import textwrap

import numpy as np
import pytest

from simtest.errors import ConfigError
from simtest.estimators import Observation, load_estimator
from simtest.estimators.icp import ICPEstimator
from simtest.estimators.oracle import OracleEstimator, axis_angle_matrix
from simtest.estimators.umeyama import ransac_umeyama, umeyama
from simtest.evaluation.run import load_dataset_objects
from simtest.io import bop
from simtest.metrics import adi, re, te
from simtest.metrics.bop19 import VISIB_GT_MIN


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q @ np.diag(np.sign(np.diag(r)))
    return q if np.linalg.det(q) > 0 else -q


def _observations(dataset, with_gt: bool = False):
    """(Observation, targets) for every image, targets = [(gt_id, ImageGT)] with visib_fract >= 0.1."""
    objects = load_dataset_objects(dataset)
    cam = bop.read_camera_json(dataset / "camera.json")
    for scene_dir in bop.scene_dirs(dataset / "train_pbr"):
        for im_id, info in sorted(bop.read_scene(scene_dir).items()):
            tg = [(j, g) for j, g in enumerate(info["gt"]) if g.visib_fract >= VISIB_GT_MIN]
            obs = Observation(
                rgb=bop.read_image(scene_dir, im_id), depth=bop.read_depth(scene_dir, im_id, info["depth_scale"]),
                K=info["K"], width=int(cam["width"]), height=int(cam["height"]), objects=objects,
                target_obj_ids=tuple(g.obj_id for _, g in tg),
                masks=tuple(bop.read_mask(scene_dir, im_id, j) for j, _ in tg),
                gt_poses=tuple((g.T_cam_obj.R, g.T_cam_obj.t) for _, g in tg) if with_gt else None,
                scene_id=int(scene_dir.name), im_id=im_id)
            yield obs, tg


# --- umeyama ---------------------------------------------------------------------------------------------
def test_umeyama_recovers_exact_similarity():
    rng = np.random.default_rng(1)
    src = rng.normal(size=(50, 3))
    R, t, s = _random_rotation(rng), rng.normal(size=3), 1.7
    s_e, R_e, t_e = umeyama(src, s * src @ R.T + t)
    assert s_e == pytest.approx(s, abs=1e-9)
    np.testing.assert_allclose(R_e, R, atol=1e-9)
    np.testing.assert_allclose(t_e, t, atol=1e-9)
    s1, R1, _ = umeyama(src, src @ R.T + t, with_scale=False)
    assert s1 == 1.0 and np.allclose(R1, R, atol=1e-9)
    with pytest.raises(ConfigError, match="at least 3"):
        umeyama(src[:2], src[:2])


def test_ransac_umeyama_with_30_percent_outliers():
    rng = np.random.default_rng(2)
    src = rng.uniform(-0.05, 0.05, size=(200, 3))
    R, t, s = _random_rotation(rng), np.array([0.1, -0.05, 0.8]), 0.8
    dst = s * src @ R.T + t + rng.normal(scale=0.0005, size=src.shape)
    out = rng.choice(200, 60, replace=False)
    dst[out] = rng.uniform(-0.2, 0.2, size=(60, 3)) + t
    s_e, R_e, t_e, inl = ransac_umeyama(src, dst, threshold=0.003, iterations=200, rng=np.random.default_rng(0))
    assert s_e == pytest.approx(s, rel=5e-3)
    assert re(R_e, R) < 0.5
    assert np.linalg.norm(t_e - t) < 1e-3
    assert inl.sum() >= 135 and not inl[out].any()
    # A plain least-squares fit is ruined by the outliers.
    s_ls, R_ls, _ = umeyama(src, dst)
    assert re(R_ls, R) > 5 or abs(s_ls - s) > 0.05


def test_umeyama_nocs_oracle_recovers_pose_and_scale(small_dataset):
    est = load_estimator("umeyama", correspondences="nocs-oracle", outlier_rate=0.3, nocs_noise_mm=0.5,
                         reference_set=None)
    assert est.needs_gt
    obs, tg = next(_observations(small_dataset, with_gt=True))
    out = est.estimate(obs)
    assert len(out) == len(tg)
    for e in out:
        g = tg[e.target_index][1]
        assert re(e.R, g.T_cam_obj.R) < 2.0 and te(e.t, g.T_cam_obj.t) < 0.003
        assert e.scale == pytest.approx(1.0, abs=0.02)  # reference = the target itself here


# --- oracle ----------------------------------------------------------------------------------------------
def test_oracle_fixed_noise_has_exact_magnitude(small_dataset):
    obs, tg = next(_observations(small_dataset, with_gt=True))
    exact = OracleEstimator().estimate(obs)
    for e, (_, g) in zip(exact, tg):
        np.testing.assert_array_equal(e.R, g.T_cam_obj.R)
        np.testing.assert_array_equal(e.t, g.T_cam_obj.t)
    noisy = OracleEstimator(rot_noise_deg=5, trans_noise_mm=5, rot_noise_mode="fixed", seed=3).estimate(obs)
    for e, (_, g) in zip(noisy, tg):
        assert re(e.R, g.T_cam_obj.R) == pytest.approx(5.0, abs=1e-6)
        assert te(e.t, g.T_cam_obj.t) == pytest.approx(0.005, abs=1e-12)
    again = OracleEstimator(rot_noise_deg=5, trans_noise_mm=5, rot_noise_mode="fixed", seed=3).estimate(obs)
    assert all(np.array_equal(a.R, b.R) for a, b in zip(noisy, again))
    assert OracleEstimator(drop_rate=1.0).estimate(obs) == []
    with pytest.raises(ConfigError, match="rot_noise_mode"):
        OracleEstimator(rot_noise_mode="gauss")
    with pytest.raises(ConfigError, match="gt_poses"):
        OracleEstimator().estimate(next(_observations(small_dataset))[0])


# --- icp -------------------------------------------------------------------------------------------------
def test_icp_recovers_clean_synthetic_poses(small_dataset):
    est = ICPEstimator()
    rows = []
    for obs, tg in _observations(small_dataset):
        for e in est.estimate(obs):
            g = tg[e.target_index][1]
            obj = obs.objects.get(e.obj_id)
            rows.append((obj.is_symmetric, g.visib_fract, re(e.R, g.T_cam_obj.R), te(e.t, g.T_cam_obj.t),
                         adi(e.R, e.t, g.T_cam_obj.R, g.T_cam_obj.t, obj.vertices)))
    nonsym = [r for r in rows if not r[0] and r[1] > 0.8]
    sym = [r for r in rows if r[0] and r[1] > 0.8]
    assert len(nonsym) >= 4 and len(sym) >= 4
    good = [r for r in nonsym if r[2] < 3.0 and r[3] < 0.003]  # within 3 degrees and 3 mm
    assert len(good) >= 0.7 * len(nonsym), nonsym
    assert np.median([r[2] for r in nonsym]) < 2.0
    # Symmetric objects: the pose is ambiguous, the surface is not (ADD-S within 5 mm).
    assert np.mean([r[4] < 0.005 for r in sym]) >= 0.8, sym


def test_icp_reports_failures_without_estimates(small_dataset):
    obs, tg = next(_observations(small_dataset))
    empty = tuple(np.zeros_like(m) for m in obs.masks)
    tiny = tuple(np.zeros_like(m) for m in obs.masks)
    for m in tiny:
        m[0, :5] = True
    est = ICPEstimator()
    import dataclasses

    assert est.estimate(dataclasses.replace(obs, masks=empty)) == []
    assert [f["reason"] for f in est.last_failures] == ["empty mask"] * len(tg)
    assert est.estimate(dataclasses.replace(obs, masks=tiny)) == []
    assert all("too few points" in f["reason"] for f in est.last_failures)
    with pytest.raises(ConfigError, match="targets='gt-masks'"):
        est.estimate(dataclasses.replace(obs, masks=None))


# --- loading ---------------------------------------------------------------------------------------------
def test_load_user_estimator_with_options(tmp_path, monkeypatch):
    (tmp_path / "my_estimators.py").write_text(textwrap.dedent("""
        from simtest.estimators import PoseEstimate

        class Const:
            def __init__(self, depth=0.5, label="x"):
                self.depth, self.label = depth, label

            def estimate(self, observation):
                import numpy as np
                return [PoseEstimate(obj_id=o, R=np.eye(3), t=np.array([0.0, 0.0, self.depth]))
                        for o in observation.target_obj_ids]
        """))
    monkeypatch.syspath_prepend(str(tmp_path))
    est = load_estimator("my_estimators:Const", depth=0.7, label="y")
    assert est.depth == 0.7 and est.label == "y"
    with pytest.raises(ConfigError, match="bad options"):
        load_estimator("my_estimators:Const", nope=1)
    sys.modules.pop("my_estimators", None)
    for name in ("oracle", "icp", "umeyama"):
        assert hasattr(load_estimator(name), "estimate")
    assert load_estimator("oracle", rot_noise_deg=2.0).rot_noise == pytest.approx(np.radians(2.0))
    assert np.allclose(axis_angle_matrix(np.array([0.0, 0.0, 1.0]), np.pi / 2) @ [1, 0, 0], [0, 1, 0])
