"""The ``icp`` estimator: instance-level, depth-only pose from a segmented point cloud.

Per target (``Observation.target_obj_ids`` with ``Observation.masks``):

1. **Segment and back-project.** Pixels of the visible mask with valid depth become camera-frame points
   ``x = (u - cx) z / fx, y = (v - cy) z / fy`` (pixel centres at integer coordinates, planar depth ``z`` in
   metres). Points farther than one object diameter from the median point are dropped (mask bleeding at depth
   edges), and at most ``max_points`` are kept (seeded subsampling).
2. **Model.** ``model_points`` area-uniform surface samples with their face normals (metres), drawn once per
   object with a fixed seed. Only points whose normal faces the camera take part (visibility by back-face
   culling along the viewing ray to the object).
3. **Coarse search.** ``coarse_rotations`` rotations (Fibonacci-sphere viewpoints x evenly spaced in-plane
   angles). For each, the translation puts the centroid of the model points visible from that view on the
   centroid of the observed points; the candidate is scored by
   ``mean(min(d_i, tau)) / tau + silhouette_weight * v``: ``d_i`` is the distance of each observed point to
   the model surface (one static KD-tree, observed points mapped into the model frame), ``tau = 0.1 x
   diameter``, and ``v`` the fraction of visible model points that project inside the image onto a valid
   depth more than ``tau`` *behind* them outside the mask (the object would be seen there: a free-space
   violation). The best ``refine_top`` candidates that are distinct modulo the object's symmetries (more
   than 20 degrees apart after the symmetry set is applied) are refined.
4. **Refine.** Point-to-plane ICP (Chen & Medioni): observed points matched to their nearest visible model
   point (``scipy.spatial.cKDTree``), correspondences farther than ``max(3 x median, 2 mm)`` rejected, a
   linearised 6-DoF least-squares step about the observed centroid, until the step is below 1e-5 rad and
   1e-6 m or ``max_iterations``. The refined candidate with the best score wins.
5. **Report.** ``score`` = fraction of observed points within ``inlier_threshold_mm`` of the posed model;
   ``info`` holds ``rmse_m``, ``fitness``, ``iterations``, ``converged``, ``num_points``. No estimate, with
   a reason in :attr:`ICPEstimator.last_failures`, for an empty mask, too few points, or a result whose
   fitness is below ``min_fitness`` (non-convergence).

Continuous and discrete symmetries leave the pose ambiguous; any symmetric equivalent is returned, so compare
with symmetry-aware errors (ADD-S, MSSD, MSPD).
"""

from __future__ import annotations

import hashlib
import importlib
import logging
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from simtest.camera import backproject, pinhole_pixels
from simtest.errors import ConfigError
from simtest.estimators.base import Observation, PoseEstimate
from simtest.estimators.options import check_int_options

#: Sources of the object masks (the ``masks`` option).
MASK_SOURCES = ("gt", "segicp")
#: The segmentation network of each mask source other than ``gt``, as ``module:attr`` (imported on first use).
#: The network owns its composition with this estimator's fit (``fit_regions(icp, observation)``, see
#: :mod:`simtest.estimators.segicp`); this module knows it by name only.
SEGMENTERS = {"segicp": "simtest.estimators.segicp.infer:Segmenter"}

__all__ = ["ICPEstimator", "MASK_SOURCES", "SEGMENTERS", "fibonacci_rotations", "ModelCloud", "model_cloud",
           "point_to_plane_icp"]

log = logging.getLogger(__name__)


def fibonacci_rotations(count: int, inplane: int | None = None) -> np.ndarray:
    """About ``count`` rotations (model -> camera) covering SO(3) evenly: viewpoints on a Fibonacci sphere
    times evenly spaced in-plane angles.

    Args:
        count: Approximate number of rotations.
        inplane: In-plane angles per viewpoint (default ``round(count ** (1/3) * 1.4)``).

    Returns:
        (M, 3, 3) rotations; the camera looks at the model origin from each viewpoint.
    """
    if count < 1:
        raise ConfigError(f"coarse_rotations must be >= 1, got {count!r}")
    n_in = int(inplane) if inplane else max(1, int(round(count ** (1.0 / 3.0) * 1.4)))
    n_view = max(1, int(round(count / n_in)))
    i = np.arange(n_view) + 0.5
    zc = 1.0 - 2.0 * i / n_view
    phi = np.pi * (1.0 + 5 ** 0.5) * i
    r = np.sqrt(np.maximum(0.0, 1.0 - zc * zc))
    dirs = np.stack([r * np.cos(phi), r * np.sin(phi), zc], axis=1)  # model frame, origin -> camera
    out = []
    for d in dirs:
        f = -d  # camera z axis in model coordinates
        helper = np.array([0.0, 0.0, 1.0]) if abs(f[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
        x = np.cross(f, helper)
        x /= np.linalg.norm(x)
        y = np.cross(f, x)
        R0 = np.stack([x, y, f])  # rows: camera axes in model coordinates -> maps model into camera
        for k in range(n_in):
            a = 2.0 * np.pi * k / n_in
            c, s = np.cos(a), np.sin(a)
            out.append(np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ R0)
    return np.asarray(out)


class ModelCloud:
    """Surface samples (N, 3) and unit normals (N, 3) of a model, metres, with a KD-tree over the points."""

    def __init__(self, points: np.ndarray, normals: np.ndarray, diameter: float, area: float) -> None:
        self.points = points
        self.normals = normals
        self.diameter = float(diameter)
        #: Typical distance between neighbouring samples, metres.
        self.spacing = float(np.sqrt(area / len(points)))
        self.tree = cKDTree(points)

    _GRID = 48

    def nearest_fast(self, q: np.ndarray) -> np.ndarray:
        """Index of (approximately) the nearest sample of each model-frame point (N, 3): a lookup in a
        precomputed 48^3 voxel grid over the bounding box plus a margin of half the diameter (points outside
        are clamped to the grid). Exact up to half a voxel diagonal."""
        if not hasattr(self, "_grid"):
            lo = self.points.min(axis=0) - 0.5 * self.diameter
            hi = self.points.max(axis=0) + 0.5 * self.diameter
            n = self._GRID
            axes = [lo[i] + (np.arange(n) + 0.5) * (hi[i] - lo[i]) / n for i in range(3)]
            centres = np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)
            _, idx = self.tree.query(centres, k=1)
            self._grid = idx.reshape(n, n, n).astype(np.int32)
            self._lo, self._inv = lo, n / (hi - lo)
        ijk = np.clip(((q - self._lo) * self._inv).astype(np.int64), 0, self._GRID - 1)
        return self._grid[ijk[:, 0], ijk[:, 1], ijk[:, 2]]

    def surface_distance(self, q: np.ndarray, fast: bool = False) -> np.ndarray:
        """Approximate distance (metres) of model-frame points (N, 3) to the surface: the point-to-plane
        distance to the nearest sample when it is within two sample spacings, else the point distance.
        ``fast`` finds the nearest sample with :meth:`nearest_fast` instead of the KD-tree."""
        if fast:
            idx = self.nearest_fast(q)
            d = np.linalg.norm(q - self.points[idx], axis=1)
        else:
            d, idx = self.tree.query(q, k=1)
        d_pl = np.abs(((q - self.points[idx]) * self.normals[idx]).sum(axis=1))
        return np.where(d < 2.0 * self.spacing, d_pl, d)


_CLOUDS: dict[tuple[str, int], ModelCloud] = {}


def _exact_mesh_key(obj: Any) -> str:
    """SHA-1 of the mesh's exact vertex and face bytes (cached on the instance).

    Not ``mesh_hash``: that rounds the vertices, so a model read back from a dataset's PLY (millimetres,
    float32) shares it with the in-memory original while its samples differ in the last bits, and a cloud cached
    for one would move the other's ICP result by ~1e-7 depending on which this process met first.
    """
    cached = getattr(obj, "__dict__", {}).get("_exact_mesh_key")
    if cached is not None:
        return cached
    mesh = getattr(obj, "mesh", None)
    if mesh is None:
        return str(id(obj))
    h = hashlib.sha1()
    h.update(np.ascontiguousarray(mesh.vertices, dtype=np.float64).tobytes())
    h.update(np.ascontiguousarray(mesh.faces, dtype=np.int64).tobytes())
    key = h.hexdigest()
    if hasattr(obj, "__dict__"):
        obj.__dict__["_exact_mesh_key"] = key
    return key


def model_cloud(obj: Any, count: int = 2000) -> ModelCloud:
    """Area-uniform surface samples with face normals of the model (:meth:`ObjectModel.surface_cloud`), with a
    KD-tree (cached per exact mesh and count, so the result never depends on which models this process met
    before)."""
    key = (_exact_mesh_key(obj), int(count))
    if key not in _CLOUDS:
        _CLOUDS[key] = ModelCloud(*obj.surface_cloud(int(count)), float(obj.diameter), float(obj.mesh.area))
    return _CLOUDS[key]


def _exp(w: np.ndarray) -> np.ndarray:
    th = float(np.linalg.norm(w))
    if th < 1e-12:
        return np.eye(3)
    k = w / th
    Kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(th) * Kx + (1.0 - np.cos(th)) * (Kx @ Kx)


def visible_points(cloud: ModelCloud, dirs: np.ndarray, step: int = 1) -> np.ndarray:
    """Which model samples are seen along each viewing direction (orthographic z-buffer on a coarse grid).

    A sample is visible when its normal faces the viewer and it lies within one grid cell of the nearest
    sample of its cell (cell = diameter / 24), which removes self-occluded surfaces (a mug's far wall and
    inside) that back-face culling alone keeps.

    Args:
        cloud: Model samples and normals (model frame).
        dirs: (M, 3) unit viewing directions (camera -> object) in the model frame.
        step: Use every ``step``-th sample.

    Returns:
        (M, N // step) bool.
    """
    P, Nrm = cloud.points[::step], cloud.normals[::step]
    dirs = np.atleast_2d(dirs)
    M = len(dirs)
    helper = np.where(np.abs(dirs[:, 2:3]) < 0.9, [[0.0, 0.0, 1.0]], [[1.0, 0.0, 0.0]])
    e1 = np.cross(dirs, helper)
    e1 /= np.linalg.norm(e1, axis=1, keepdims=True)
    e2 = np.cross(dirs, e1)
    cell = cloud.diameter / 24.0
    G = 28
    ia = np.clip(np.floor((P @ e1.T) / cell).astype(np.int64) + G // 2, 0, G - 1).T  # (M, N)
    ib = np.clip(np.floor((P @ e2.T) / cell).astype(np.int64) + G // 2, 0, G - 1).T
    depth = (P @ dirs.T).T  # larger = farther from the viewer
    key = (np.arange(M)[:, None] * G + ia) * G + ib
    zmin = np.full(M * G * G, np.inf)
    np.minimum.at(zmin, key.ravel(), depth.ravel())
    facing = (Nrm @ dirs.T).T < 0
    return facing & (depth <= zmin[key] + cell)


def _visible(cloud: ModelCloud, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Model samples seen by the camera at pose ``(R, t)`` (viewing ray to the object's origin)."""
    ray = t / max(float(np.linalg.norm(t)), 1e-9)
    return visible_points(cloud, (R.T @ ray)[None])[0]


def point_to_plane_icp(obs: np.ndarray, cloud: ModelCloud, R: np.ndarray, t: np.ndarray, max_iterations: int = 30,
                       min_reject: float = 0.002) -> tuple[np.ndarray, np.ndarray, int, bool]:
    """Refine a pose (model -> camera) with point-to-plane ICP against the camera-facing model points.

    Args:
        obs: Observed camera-frame points (N, 3), metres.
        cloud: Model samples and normals.
        R, t: Initial pose (t in metres).
        max_iterations: Iteration limit.
        min_reject: Lower bound (metres) of the correspondence rejection distance ``max(3 median, min_reject)``.

    Returns:
        ``(R, t, iterations, converged)``.
    """
    c = obs.mean(axis=0)
    R, t = R.copy(), t.copy()
    for it in range(1, max_iterations + 1):
        vis = _visible(cloud, R, t)
        if np.count_nonzero(vis) < 6:
            vis[:] = True
        mp = cloud.points[vis] @ R.T + t
        mn = cloud.normals[vis] @ R.T
        d, idx = cKDTree(mp).query(obs, k=1)
        keep = d <= max(3.0 * float(np.median(d)), min_reject)
        if np.count_nonzero(keep) < 6:
            return R, t, it, False
        p, m, n = obs[keep], mp[idx[keep]], mn[idx[keep]]
        A = np.concatenate([np.cross(m - c, n), n], axis=1)
        b = np.einsum("ij,ij->i", p - m, n)
        x, *_ = np.linalg.lstsq(A, b, rcond=None)
        w, v = x[:3], x[3:]
        dR = _exp(w)
        R = dR @ R
        t = dR @ (t - c) + c + v
        if np.linalg.norm(w) < 1e-5 and np.linalg.norm(v) < 1e-6:
            return R, t, it, True
    return R, t, max_iterations, False


def _sym_rotations(obj: Any) -> np.ndarray:
    if hasattr(obj, "symmetry_transforms") and getattr(obj, "is_symmetric", False):
        return np.asarray(obj.symmetry_transforms(max_step=0.1))[:, :3, :3]
    return np.eye(3)[None]


class ICPEstimator:
    """Depth-only instance-level pose: coarse rotation search + point-to-plane ICP (see the module doc).

    Args:
        max_iterations: ICP iterations per refined candidate.
        coarse_rotations: Number of rotations in the coarse search (about; Fibonacci viewpoints x in-plane).
        refine_top: Distinct coarse candidates refined by ICP.
        model_points: Surface samples per model.
        max_points: Observed points kept per target (seeded subsampling).
        coarse_points: Observed points used to score coarse candidates.
        min_points: Fewer valid masked depth pixels than this -> no estimate.
        inlier_threshold_mm: Distance (millimetres) within which an observed point counts as explained.
        min_fitness: Fraction of inliers below which the result is rejected (no estimate).
        silhouette_weight: Weight of the free-space violation term of the candidate score.
        seed: Seed of the point subsampling (combined with scene and image ids).
        masks: Where the object pixels come from: ``"gt"``, the observation's ground-truth visible masks
            (the estimator declares ``needs_gt_masks`` and is labelled ``icp (GT masks)``), or ``"segicp"``,
            the segmentation network of :mod:`simtest.estimators.segicp` (no ground truth read).
        checkpoint: Segmentation checkpoint for ``masks="segicp"`` (default: the shipped one, for
            ``builtin-small``).
    """

    #: Whether the evaluation passes ground-truth visible masks (instances: ``masks == "gt"``).
    needs_gt_masks = True

    def __init__(self, max_iterations: int = 30, coarse_rotations: int = 600, refine_top: int = 4,
                 model_points: int = 2000, max_points: int = 800, coarse_points: int = 100, min_points: int = 30,
                 inlier_threshold_mm: float = 5.0, min_fitness: float = 0.5, silhouette_weight: float = 1.0,
                 seed: int = 0, masks: str = "gt", checkpoint: str | None = None) -> None:
        if masks not in MASK_SOURCES:
            raise ConfigError(f"icp: masks must be one of {', '.join(MASK_SOURCES)}, got {masks!r}")
        if checkpoint is not None and masks != "segicp":
            raise ConfigError(f"icp: checkpoint={checkpoint!r} is a segmentation checkpoint; it needs "
                              "masks='segicp'")
        check_int_options("icp", ("max_iterations", max_iterations, 1), ("coarse_rotations", coarse_rotations, 1),
                          ("refine_top", refine_top, 1), ("model_points", model_points, 10),
                          ("max_points", max_points, 10), ("coarse_points", coarse_points, 10),
                          ("min_points", min_points, 3), ("seed", seed, 0))
        if not inlier_threshold_mm > 0:
            raise ConfigError(f"icp: inlier_threshold_mm must be > 0 millimetres, got {inlier_threshold_mm!r}")
        if not 0.0 <= min_fitness <= 1.0:
            raise ConfigError(f"icp: min_fitness must be in [0, 1], got {min_fitness!r}")
        self.max_iterations = int(max_iterations)
        self.refine_top = int(refine_top)
        self.model_points = int(model_points)
        self.max_points = int(max_points)
        self.coarse_points = int(coarse_points)
        self.min_points = int(min_points)
        self.inlier_threshold = float(inlier_threshold_mm) / 1000.0  # option in mm; metres inside
        self.min_fitness = float(min_fitness)
        self.silhouette_weight = float(silhouette_weight)
        self.seed = int(seed)
        self.rotations = fibonacci_rotations(int(coarse_rotations))
        self.last_failures: list[dict[str, Any]] = []
        self.masks = masks
        self.needs_gt_masks = masks == "gt"
        #: The segmentation network that finds the objects (None: the observation's ground-truth masks).
        self.segmenter: Any = None
        if masks != "gt":
            module, _, attr = SEGMENTERS[masks].partition(":")
            self.segmenter = getattr(importlib.import_module(module), attr)(checkpoint)

    # --- scoring -------------------------------------------------------------------------------------------
    @staticmethod
    def _fit(obs_pts: np.ndarray, cloud: ModelCloud, Rs: np.ndarray, ts: np.ndarray, tau: float,
             fast: bool = False) -> np.ndarray:
        """``mean(min(d_i, tau)) / tau`` per candidate, ``d_i`` the surface distance of each observed point."""
        q = np.matmul(obs_pts[None] - ts[:, None, :], Rs)  # rows R^T (p - t)
        d = cloud.surface_distance(q.reshape(-1, 3), fast=fast)
        return np.minimum(d.reshape(len(Rs), -1), tau).mean(axis=1) / tau

    @staticmethod
    def _violation(cloud: ModelCloud, Rs: np.ndarray, ts: np.ndarray, ctx: dict[str, Any], tau: float
                   ) -> np.ndarray:
        """Fraction of camera-facing model points seen in free space: projected outside the mask onto a valid
        depth more than ``tau`` behind them."""
        K, mask, depth = ctx["K"], ctx["mask"], ctx["depth"]
        h, w = mask.shape
        P, N = cloud.points[::4], cloud.normals[::4]
        pc = np.matmul(P[None], Rs.transpose(0, 2, 1)) + ts[:, None, :]
        nc = np.matmul(N[None], Rs.transpose(0, 2, 1))
        vis = (pc * nc).sum(axis=2) < 0
        u, v = (np.rint(c).astype(np.int64) for c in pinhole_pixels(K, pc, np.maximum(pc[..., 2], 1e-6)))
        inside = (u >= 0) & (u < w) & (v >= 0) & (v < h) & vis
        uu, vv = np.clip(u, 0, w - 1), np.clip(v, 0, h - 1)
        dobs = depth[vv, uu]
        viol = inside & ~mask[vv, uu] & (dobs > pc[..., 2] + tau)
        return viol.sum(axis=1) / np.maximum(vis.sum(axis=1), 1)

    def _cost(self, obs_pts: np.ndarray, cloud: ModelCloud, Rs: np.ndarray, ts: np.ndarray, ctx: dict[str, Any],
              tau: float) -> np.ndarray:
        """Candidate costs (lower is better): surface fit plus weighted free-space violation."""
        c = self._fit(obs_pts, cloud, Rs, ts, tau)
        if self.silhouette_weight > 0:
            c = c + self.silhouette_weight * self._violation(cloud, Rs, ts, ctx, max(tau, 0.01 * cloud.diameter))
        return c

    def _init_translations(self, cloud: ModelCloud, Rs: np.ndarray, centroid: np.ndarray) -> np.ndarray:
        ray = centroid / np.linalg.norm(centroid)
        d_model = np.einsum("mji,j->mi", Rs, ray)  # viewing ray in each candidate's model frame
        # Visible points weighted by their projected area (|cos| of the normal to the ray), as the pixels of
        # a depth image sample the surface.
        step = 2
        vis = visible_points(cloud, d_model, step)  # (M, N / step)
        wgt = vis * np.maximum(-(d_model @ cloud.normals[::step].T), 0.0)
        c_vis = (wgt @ cloud.points[::step]) / np.maximum(wgt.sum(axis=1), 1e-12)[:, None]  # (M, 3)
        return centroid[None] - np.einsum("mij,mj->mi", Rs, c_vis)

    # --- estimation ------------------------------------------------------------------------------------------
    def _fail(self, obj_id: int, k: int | None, reason: str, obs: Observation) -> None:
        log.info("icp: scene %d image %d target %s (obj %d): %s", obs.scene_id, obs.im_id, k, obj_id, reason)
        self.last_failures.append({"obj_id": int(obj_id), "target_index": k, "reason": reason})

    def estimate(self, observation: Observation) -> list[PoseEstimate]:
        """One estimate per target with enough depth (see the module doc).

        With ``masks="gt"`` the targets' visible masks come from the observation; with ``masks="segicp"``
        from the segmentation network of :mod:`simtest.estimators.segicp`.

        Raises:
            ConfigError: ``masks="gt"`` and the observation has no targets or masks.
        """
        self.last_failures = []
        obs = observation
        if self.segmenter is not None:
            return self.segmenter.fit_regions(self, obs)
        if obs.target_obj_ids is None or obs.masks is None:
            raise ConfigError("icp: needs the targets' ground-truth visible masks (evaluate with "
                              "targets='gt-masks'), or use masks='segicp' (or the segicp estimator) to find the "
                              "objects with the segmentation network")
        rng = obs.rng(self.seed)
        out = []
        for k, (obj_id, mask) in enumerate(zip(obs.target_obj_ids, obs.masks)):
            est = self.fit_mask(obs, int(obj_id), np.asarray(mask, dtype=bool), k, rng)
            if est is not None:
                out.append(est)
        return out

    def fit_mask(self, obs: Observation, obj_id: int, mask: np.ndarray, k: int | None,
                 rng: np.random.Generator) -> PoseEstimate | None:
        """The pose of object ``obj_id`` from the depth pixels of ``mask`` (H, W) bool, or None (the reason
        appended to :attr:`last_failures`).

        Args:
            obs: The observation (depth in metres, ``K``, the object set).
            obj_id: Object id whose model is fitted.
            mask: Pixels of the object (ground-truth or predicted).
            k: Target index the estimate answers (None: found by the estimator itself).
            rng: Generator of the point subsampling.
        """
        K = np.asarray(obs.K, dtype=np.float64)
        depth = np.asarray(obs.depth, dtype=np.float64)
        if not mask.any():
            self._fail(obj_id, k, "empty mask", obs)
            return None
        pts = backproject(depth, K, mask)
        if len(pts) < self.min_points:
            self._fail(obj_id, k, f"too few points: {len(pts)} valid depth pixels in the mask "
                                  f"(min_points={self.min_points})", obs)
            return None
        obj = obs.objects.get(obj_id)
        cloud = model_cloud(obj, self.model_points)
        med = np.median(pts, axis=0)
        pts = pts[np.linalg.norm(pts - med, axis=1) <= cloud.diameter]
        if len(pts) < self.min_points:
            self._fail(obj_id, k, f"too few points after outlier removal: {len(pts)}", obs)
            return None
        if len(pts) > self.max_points:
            pts = pts[rng.choice(len(pts), self.max_points, replace=False)]
        R, t, info = self._estimate_one(pts, cloud, obj, {"K": K, "mask": mask, "depth": depth}, rng)
        if info["fitness"] < self.min_fitness:
            self._fail(obj_id, k, f"not converged: fitness {info['fitness']:.2f} < min_fitness "
                                  f"{self.min_fitness} (rmse {info['rmse_m'] * 1000:.1f} mm)", obs)
            return None
        return PoseEstimate(obj_id=int(obj_id), R=R, t=t, score=float(info["fitness"]), target_index=k, info=info)

    def _estimate_one(self, pts: np.ndarray, cloud: ModelCloud, obj: Any, ctx: dict[str, Any],
                      rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, dict[str, Any]]:
        centroid = pts.mean(axis=0)
        sub = pts if len(pts) <= self.coarse_points else pts[rng.choice(len(pts), self.coarse_points, replace=False)]
        tau = 0.1 * cloud.diameter
        Rs = self.rotations
        ts = self._init_translations(cloud, Rs, centroid)
        # Two translation-only point-to-point steps per rotation: t += R mean(q - nearest model sample).
        for _ in range(2):
            for i in range(0, len(Rs), 200):
                q = np.matmul(sub[None] - ts[i:i + 200, None, :], Rs[i:i + 200])
                idx = cloud.nearest_fast(q.reshape(-1, 3))
                delta = (q - cloud.points[idx].reshape(q.shape)).mean(axis=1)
                ts[i:i + 200] += np.einsum("mij,mj->mi", Rs[i:i + 200], delta)
        # Coarse: surface fit for every rotation, then the silhouette term for the best few.
        fit = np.concatenate([self._fit(sub, cloud, Rs[i:i + 200], ts[i:i + 200], tau, fast=True)
                              for i in range(0, len(Rs), 200)])
        top = np.argsort(fit, kind="stable")[:max(8 * self.refine_top, 32)]
        costs = self._cost(sub, cloud, Rs[top], ts[top], ctx, tau)
        # Distinct starts modulo the object's symmetries.
        syms = _sym_rotations(obj)
        starts: list[int] = []
        for i in top[np.argsort(costs, kind="stable")]:
            ok = True
            for j in starts:
                tr = np.einsum("ij,sij->s", Rs[j].T @ Rs[i], syms).max()
                if np.arccos(np.clip(0.5 * (tr - 1.0), -1.0, 1.0)) < np.radians(20.0):
                    ok = False
                    break
            if ok:
                starts.append(int(i))
            if len(starts) >= self.refine_top:
                break
        # Short ICP from every start on a subsample; the best (fine cost) continues on all points.
        fine_tau = self.inlier_threshold
        short = pts if len(pts) <= 300 else pts[rng.choice(len(pts), 300, replace=False)]
        best = None
        for i in starts:
            R, t, _, _ = point_to_plane_icp(short, cloud, Rs[i], ts[i], min(8, self.max_iterations))
            c = float(self._cost(pts, cloud, R[None], t[None], ctx, fine_tau)[0])
            if best is None or c < best[0]:
                best = (c, R, t)
        R, t, iters, conv = point_to_plane_icp(pts, cloud, best[1], best[2], self.max_iterations)
        c = float(self._cost(pts, cloud, R[None], t[None], ctx, fine_tau)[0])
        # Orthonormalise (accumulated round-off).
        U, _, Vt = np.linalg.svd(R)
        R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
        d = cloud.surface_distance((pts - t) @ R)
        fitness = float(np.mean(d < self.inlier_threshold))
        rmse = float(np.sqrt(np.mean(d[d < self.inlier_threshold] ** 2))) if fitness > 0 else float("inf")
        return R, t, {"fitness": fitness, "rmse_m": rmse, "iterations": int(iters), "converged": bool(conv),
                      "cost": c, "num_points": int(len(pts))}
