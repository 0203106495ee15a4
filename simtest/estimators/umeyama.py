"""The ``umeyama`` estimator: category-level pose and scale from 3D correspondences with a reference instance.

A category-level method does not know the target's exact model, only its category. This baseline registers
the target's observed points to a **reference instance** of the same category (by default another instance
from the ``builtin`` set, e.g. ``mug_1`` for a ``mug_0`` target) with a similarity transform
``x_cam = s R x_ref + t`` (Umeyama 1991), robustly with RANSAC. Built-in instances of a category share the
canonical frame (origin at the bbox centre, Z up, handle / stem in the same direction), so ``(R, t)`` is
also the target's pose and ``s`` its size relative to the reference.

Correspondences (``correspondences=``):

* ``"nn"`` (default, uses no ground truth): the reference is first aligned rigidly with the coarse search of
  the ``icp`` estimator (:class:`simtest.estimators.icp.ICPEstimator`); then, for ``iterations`` rounds, every
  observed point is mapped into the canonical frame (``x = R^T (p - t) / s``) and paired with its nearest
  reference surface sample, and RANSAC-Umeyama on the pairs updates ``(s, R, t)`` — a similarity ICP with
  nearest neighbours in the canonical frame.
* ``"nocs-oracle"``: a stand-in for a NOCS network. Each observed point gets its exact normalized object
  coordinate from the ground-truth pose (``x_tgt / nocs_scale_tgt``), mapped into the reference frame
  (``x nocs_scale_ref``), perturbed by ``nocs_noise_mm`` Gaussian noise, and a fraction ``outlier_rate``
  replaced by random points in the reference box. RANSAC-Umeyama then recovers ``(s, R, t)``; with no noise
  ``s = nocs_scale_tgt / nocs_scale_ref`` exactly. This mode sets ``needs_gt = True``.

The returned :class:`~simtest.estimators.base.PoseEstimate` carries ``scale`` (``s``) and ``info``
(reference name, inlier fraction).
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from simtest.errors import ConfigError
from simtest.estimators.base import Observation, PoseEstimate
from simtest.estimators.options import check_int_options
from simtest.camera import backproject
from simtest.estimators.icp import ICPEstimator, model_cloud
from simtest.objects import load_object_set

__all__ = ["umeyama", "ransac_umeyama", "UmeyamaEstimator"]

log = logging.getLogger(__name__)

_MODES = ("nn", "nocs-oracle")


def umeyama(src: np.ndarray, dst: np.ndarray, with_scale: bool = True) -> tuple[float, np.ndarray, np.ndarray]:
    """Least-squares similarity ``dst ~ s R src + t`` (Umeyama 1991, "Least-squares estimation of
    transformation parameters between two point patterns", eqs. 40-42).

    Args:
        src: (N, 3) points.
        dst: (N, 3) corresponding points (same units as ``src`` for ``t``).
        with_scale: Estimate ``s``; otherwise ``s = 1`` (the Kabsch rigid fit).

    Returns:
        ``(s, R, t)``: scale, 3x3 rotation (det +1), translation (3,) in the units of ``dst``.

    Raises:
        ConfigError: Shapes differ, fewer than 3 points, or the source points are all coincident.
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3:
        raise ConfigError(f"umeyama: src and dst must both be (N, 3), got {src.shape} and {dst.shape}")
    if len(src) < 3:
        raise ConfigError(f"umeyama: needs at least 3 correspondences, got {len(src)}")
    mu_s, mu_d = src.mean(axis=0), dst.mean(axis=0)
    xs, xd = src - mu_s, dst - mu_d
    var_s = float((xs * xs).sum() / len(src))
    if var_s <= 0:
        raise ConfigError("umeyama: source points are all coincident")
    cov = xd.T @ xs / len(src)
    U, D, Vt = np.linalg.svd(cov)
    S = np.eye(3)
    if np.linalg.det(U) * np.linalg.det(Vt) < 0:
        S[2, 2] = -1.0
    R = U @ S @ Vt
    s = float(np.trace(np.diag(D) @ S) / var_s) if with_scale else 1.0
    t = mu_d - s * R @ mu_s
    return s, R, t


def ransac_umeyama(src: np.ndarray, dst: np.ndarray, threshold: float, *, iterations: int = 200,
                   with_scale: bool = True, rng: np.random.Generator | None = None, min_inliers: int = 3
                   ) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
    """RANSAC over minimal 3-point Umeyama fits, then a least-squares refit on the best consensus set.

    Args:
        src: (N, 3) source points.
        dst: (N, 3) corresponding destination points.
        threshold: Inlier distance ``|| s R src + t - dst ||`` (units of ``dst``).
        iterations: Random minimal samples.
        with_scale: Estimate the scale.
        rng: Random generator (default ``np.random.default_rng(0)``).
        min_inliers: Fewer inliers than this raise.

    Returns:
        ``(s, R, t, inliers)`` with ``inliers`` an (N,) bool mask.

    Raises:
        ConfigError: Too few correspondences or no consensus of ``min_inliers`` points.
    """
    src = np.asarray(src, dtype=np.float64)
    dst = np.asarray(dst, dtype=np.float64)
    if src.shape != dst.shape or src.ndim != 2 or src.shape[1] != 3:
        raise ConfigError(f"ransac_umeyama: src and dst must both be (N, 3), got {src.shape} and {dst.shape}")
    n = len(src)
    if n < 3:
        raise ConfigError(f"ransac_umeyama: needs at least 3 correspondences, got {n}")
    if not threshold > 0:
        raise ConfigError(f"ransac_umeyama: threshold must be > 0, got {threshold!r}")
    rng = np.random.default_rng(0) if rng is None else rng
    best_inl, best_count = None, -1
    for _ in range(int(iterations)):
        idx = rng.choice(n, 3, replace=False)
        a = src[idx]
        # Skip near-degenerate (collinear) samples.
        if np.linalg.norm(np.cross(a[1] - a[0], a[2] - a[0])) < 1e-12:
            continue
        try:
            s, R, t = umeyama(a, dst[idx], with_scale)
        except ConfigError:
            continue
        if with_scale and not s > 0:
            continue
        err = np.linalg.norm(src @ (s * R).T + t - dst, axis=1)
        inl = err < threshold
        c = int(inl.sum())
        if c > best_count:
            best_inl, best_count = inl, c
    if best_inl is None or best_count < max(3, min_inliers):
        raise ConfigError(f"ransac_umeyama: no consensus: best {max(best_count, 0)} inliers of {n} within "
                          f"{threshold} (min_inliers={min_inliers})")
    s, R, t = umeyama(src[best_inl], dst[best_inl], with_scale)
    # One re-selection with the refined fit, then the final least-squares fit.
    inl = np.linalg.norm(src @ (s * R).T + t - dst, axis=1) < threshold
    if inl.sum() >= 3:
        s, R, t = umeyama(src[inl], dst[inl], with_scale)
        best_inl = inl
    return s, R, t, best_inl


class UmeyamaEstimator:
    """Category-level similarity registration to a reference instance (see the module doc).

    Args:
        correspondences: ``"nn"`` (no ground truth) or ``"nocs-oracle"`` (ground-truth NOCS plus noise).
        reference_set: Object set the reference instances come from (``"builtin"``, a path, or ``None`` for
            the observation's own set).
        reference_instance: Instance index of the reference; ``None``: the first instance of the category
            whose mesh differs from the target's (the target itself if there is none).
        iterations: Similarity-ICP rounds (``"nn"``).
        ransac_iterations: RANSAC minimal samples per fit.
        ransac_threshold_mm: RANSAC inlier distance, millimetres.
        nocs_noise_mm: Noise (standard deviation, millimetres, in the reference frame) of the oracle NOCS.
        outlier_rate: Fraction in [0, 1) of oracle NOCS correspondences replaced by random points.
        max_points: Observed points used per target.
        min_points: Fewer valid masked depth pixels -> no estimate.
        coarse_rotations: Rotations of the rigid coarse search (``"nn"``).
        seed: Seed (combined with scene and image ids).
    """

    #: Reads the targets' ground-truth visible masks (labelled ``umeyama (GT masks)``).
    needs_gt_masks = True

    def __init__(self, correspondences: str = "nn", reference_set: str | None = "builtin",
                 reference_instance: int | None = None, iterations: int = 10, ransac_iterations: int = 50,
                 ransac_threshold_mm: float = 5.0, nocs_noise_mm: float = 0.0, outlier_rate: float = 0.0,
                 max_points: int = 600, min_points: int = 30, coarse_rotations: int = 600, seed: int = 0) -> None:
        if correspondences not in _MODES:
            raise ConfigError(f"umeyama: correspondences must be one of {', '.join(_MODES)}, got "
                              f"{correspondences!r}")
        if not ransac_threshold_mm > 0:
            raise ConfigError(f"umeyama: ransac_threshold_mm must be > 0 millimetres, got {ransac_threshold_mm!r}")
        if not nocs_noise_mm >= 0:
            raise ConfigError(f"umeyama: nocs_noise_mm must be >= 0 millimetres, got {nocs_noise_mm!r}")
        if not 0.0 <= outlier_rate < 1.0:
            raise ConfigError(f"umeyama: outlier_rate must be in [0, 1), got {outlier_rate!r}")
        check_int_options("umeyama", ("seed", seed, 0))
        self.mode = correspondences
        self.needs_gt = correspondences == "nocs-oracle"
        self.reference_set = reference_set
        self.reference_instance = reference_instance
        self.iterations = int(iterations)
        self.ransac_iterations = int(ransac_iterations)
        self.threshold = float(ransac_threshold_mm) / 1000.0  # options in mm; metres inside
        self.nocs_noise = float(nocs_noise_mm) / 1000.0
        self.outlier_rate = float(outlier_rate)
        self.max_points = int(max_points)
        self.min_points = int(min_points)
        self.seed = int(seed)
        self._icp = ICPEstimator(coarse_rotations=coarse_rotations, seed=seed)
        self._refs: Any = None
        self.last_failures: list[dict[str, Any]] = []

    def _reference(self, target: Any, objects: Any) -> Any:
        if self.reference_set is None:
            pool = objects
        else:
            if self._refs is None:
                self._refs = load_object_set(self.reference_set)
            pool = self._refs
        same = [o for o in pool if o.category == target.category]
        if not same:
            raise ConfigError(f"umeyama: no reference of category {target.category!r} in object set "
                              f"{getattr(pool, 'name', '?')!r}; categories: {sorted({o.category for o in pool})}")
        if self.reference_instance is not None:
            for o in same:
                if o.instance == int(self.reference_instance):
                    return o
            raise ConfigError(f"umeyama: no instance {self.reference_instance} of category {target.category!r}; "
                              f"instances: {sorted(o.instance for o in same)}")
        for o in same:
            if o.mesh_hash != target.mesh_hash:
                return o
        return same[0]

    def _fail(self, obs: Observation, obj_id: int, k: int, reason: str) -> None:
        log.info("umeyama: scene %d image %d target %d (obj %d): %s", obs.scene_id, obs.im_id, k, obj_id, reason)
        self.last_failures.append({"obj_id": int(obj_id), "target_index": k, "reason": reason})

    def estimate(self, observation: Observation) -> list[PoseEstimate]:
        """One estimate (with scale) per target with enough depth.

        Raises:
            ConfigError: No targets / masks, or (oracle mode) no ground-truth poses.
        """
        self.last_failures = []
        obs = observation
        obs.require_targets("umeyama")
        if self.needs_gt and obs.gt_poses is None:
            raise ConfigError("umeyama: correspondences='nocs-oracle' needs ground-truth poses in the observation")
        rng = obs.rng(self.seed)
        K = np.asarray(obs.K, dtype=np.float64)
        depth = np.asarray(obs.depth, dtype=np.float64)
        out = []
        for k, (obj_id, mask) in enumerate(zip(obs.target_obj_ids, obs.masks)):
            mask = np.asarray(mask, dtype=bool)
            pts = backproject(depth, K, mask)
            if len(pts) < self.min_points:
                self._fail(obs, obj_id, k, f"too few points: {len(pts)} valid depth pixels in the mask "
                                           f"(min_points={self.min_points})")
                continue
            target = obs.objects.get(obj_id)
            ref = self._reference(target, obs.objects)
            if len(pts) > self.max_points:
                pts = pts[rng.choice(len(pts), self.max_points, replace=False)]
            try:
                if self.mode == "nocs-oracle":
                    s, R, t, inl = self._from_nocs(pts, target, ref, obs.gt_poses[k], rng)
                else:
                    s, R, t, inl = self._from_nn(pts, ref, mask, K, depth, rng)
            except ConfigError as exc:
                self._fail(obs, obj_id, k, str(exc))
                continue
            out.append(PoseEstimate(obj_id=int(obj_id), R=R, t=t, score=float(inl.mean()), scale=float(s),
                                    target_index=k, info={"reference": ref.name, "inlier_fraction": float(inl.mean()),
                                                          "num_points": int(len(pts))}))
        return out

    def _from_nocs(self, pts: np.ndarray, target: Any, ref: Any, gt: tuple[np.ndarray, np.ndarray],
                   rng: np.random.Generator) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        R_g, t_g = (np.asarray(a, dtype=np.float64) for a in gt)
        nocs = ((pts - t_g) @ R_g) / target.nocs_scale  # centred NOCS (unit-diagonal box)
        x_ref = nocs * ref.nocs_scale + rng.normal(scale=self.nocs_noise, size=nocs.shape) if self.nocs_noise else \
            nocs * ref.nocs_scale
        n_out = int(round(self.outlier_rate * len(pts)))
        if n_out:
            lo, hi = ref.bbox
            idx = rng.choice(len(pts), n_out, replace=False)
            x_ref[idx] = rng.uniform(lo, hi, size=(n_out, 3))
        s, R, t, inl = ransac_umeyama(x_ref, pts, self.threshold + 3.0 * self.nocs_noise,
                                      iterations=self.ransac_iterations, rng=rng, min_inliers=self.min_points)
        return s, R, t, inl

    def _from_nn(self, pts: np.ndarray, ref: Any, mask: np.ndarray, K: np.ndarray, depth: np.ndarray,
                 rng: np.random.Generator) -> tuple[float, np.ndarray, np.ndarray, np.ndarray]:
        cloud = model_cloud(ref, self._icp.model_points)
        R, t, _ = self._icp._estimate_one(pts, cloud, ref, {"K": K, "mask": mask, "depth": depth}, rng)
        s = 1.0
        inl = np.ones(len(pts), dtype=bool)
        for _ in range(self.iterations):
            q = ((pts - t) @ R) / s  # canonical (reference) frame
            _, idx = cloud.tree.query(q, k=1)
            s_new, R_new, t_new, inl = ransac_umeyama(cloud.points[idx], pts, max(self.threshold, 2.0 * cloud.spacing),
                                                      iterations=self.ransac_iterations, rng=rng,
                                                      min_inliers=self.min_points)
            done = abs(s_new - s) < 1e-5 and np.linalg.norm(t_new - t) < 1e-6
            s, R, t = s_new, R_new, t_new
            if done:
                break
        return s, R, t, inl
