"""The ``track-icp`` estimator: frame-to-frame 6-DoF tracking of known objects with point-to-plane ICP on depth.

A baseline for tracking in sequences (``simtest generate --rig sequence``). It declares ``needs_gt_init``: the
evaluation gives each target's ground-truth pose once, on the first frame of the sequence in which the target
appears (``Observation.init_poses``), plus stable track ids; its runs are labelled ``track-icp (GT init)``.
It reads no masks, boxes or later poses. Per target and frame:

1. **Predict.** The previous frame's pose ``(R_k-1, t_k-1)`` (model -> camera), with ``velocity_prior`` the
   translation extrapolated at constant velocity, ``t_k-1 + (t_k-1 - t_k-2)``. The rotation is not
   extrapolated: a spin that the depth does not constrain (about the axis of a mug whose handle is hidden)
   would otherwise compound from frame to frame.
2. **Search.** The predicted translation is replaced by the best of a grid of offsets within ``search_mm``
   (9 per axis, then a 3x finer grid of 5 around the best), scored by how well the camera-facing model samples
   placed there explain the depth image (step 4's counts: explained - violations - 0.5 occluded): a capture
   range for fast camera motion.
3. **Refine.** From the prediction and from the searched pose: depth pixels inside the image window of the
   bounding sphere are back-projected (metres); those within ``gate_mm`` of the model surface whose
   depth-image normal is within ``normal_deg`` of the nearest model sample's normal (which drops the table
   around the object's base) are kept (at most ``max_points``, seeded subsampling); point-to-plane ICP
   (:func:`simtest.estimators.icp.point_to_plane_icp`), then once more with the points within ``gate_mm / 2``.
   Of the two results, the one explaining more depth at a tolerance of ``0.3 consistency_mm`` wins.
4. **Check (loss of track).** The camera-facing model samples at the refined pose are projected into the depth
   image: a sample is *explained* when the measured depth is within ``consistency_mm`` of its depth, a
   *free-space violation* when the measured depth lies more than that behind it (the object would hide it),
   and *occluded* when in front. ``fitness = explained / (explained + violations + 0.5 occluded)``. The
   track is lost when ``fitness < min_fitness``, fewer than ``min_points`` samples are explained, or too few
   points were selected: no estimate is returned and the reason (``track lost at frame k: ...``) goes to
   :attr:`TrackICPEstimator.last_failures` (``failures.csv``, kind ``no-estimate``).
5. **After a loss** (``on_loss``): ``"stop"`` (default) gives no more estimates for the track; ``"retry"``
   tries again each frame from the last accepted pose (without the velocity prior) and resumes when the
   check passes.

``init_rot_deg`` / ``init_trans_mm`` perturb the initial pose by a fixed angle about a random axis and a fixed
offset in a random direction (seeded by ``seed``, scene and track), to measure robustness to the initialisation;
state them with the results.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import Any

import numpy as np

from simtest.camera import pinhole_pixels, pinhole_points
from simtest.errors import ConfigError
from simtest.geometry import as_matrix
from simtest.estimators.base import Observation, PoseEstimate
from simtest.estimators.options import check_int_options
from simtest.estimators.icp import ModelCloud, model_cloud, point_to_plane_icp, visible_points
from simtest.estimators.oracle import axis_angle_matrix, random_unit_vector

__all__ = ["TrackICPEstimator", "LOSS_POLICIES", "OCCLUDED_WEIGHT", "depth_consistency"]

log = logging.getLogger(__name__)

#: Weight of an occluded model sample in the search score and the fitness: a pose buried in a surface (a can
#: sunk into the table so that only its top face meets the depth) must not look as good as the right one, while
#: a real occluder costs only half.
OCCLUDED_WEIGHT = 0.5

#: What happens after a track is lost (the ``on_loss`` option).
LOSS_POLICIES = ("stop", "retry")


def depth_consistency(depth: np.ndarray, K: np.ndarray, cloud: ModelCloud, R: np.ndarray, t: np.ndarray,
                      tol: float) -> tuple[int, int, int]:
    """``(explained, violations, occluded)``: camera-facing model samples at pose ``(R, t)`` whose measured depth
    is within ``tol`` metres of theirs, those whose measured depth is more than ``tol`` behind them (free space),
    and those with a measured depth more than ``tol`` in front of them (hidden by something else).

    Args:
        depth: (H, W) planar depth, metres, 0 = missing (ignored).
        K: 3x3 intrinsics, pixels.
        cloud: Model samples and normals (model frame).
        R, t: Pose model -> camera (metres).
        tol: Tolerance, metres.
    """
    ray = t / max(float(np.linalg.norm(t)), 1e-9)
    vis = visible_points(cloud, (R.T @ ray)[None])[0]
    P = cloud.points[vis] @ R.T + t
    P = P[P[:, 2] > 1e-3]
    h, w = depth.shape
    u, v = (np.rint(c).astype(np.int64) for c in pinhole_pixels(K, P))
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    d = depth[v[inside], u[inside]]
    z = P[inside, 2]
    valid = d > 0
    explained = int(np.count_nonzero(valid & (np.abs(d - z) <= tol)))
    violations = int(np.count_nonzero(valid & (d > z + tol)))
    return explained, violations, int(np.count_nonzero(valid & (d < z - tol)))


def point_and_normal_maps(depth: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame points (H, W, 3) and unit normals (H, W, 3) of a depth image, metres.

    ``x = (u - cx) z / fx, y = (v - cy) z / fy`` as :func:`simtest.camera.backproject`; the normal is the
    cross product of the differences to the right and lower neighbours, turned toward the camera. Pixels without
    depth, or with a neighbour without depth, have a zero normal.
    """
    h, w = depth.shape
    v, u = np.mgrid[0:h, 0:w]
    P = pinhole_points(K, u, v, depth)
    du = np.zeros_like(P)
    dv = np.zeros_like(P)
    du[:, :-1] = P[:, 1:] - P[:, :-1]
    dv[:-1] = P[1:] - P[:-1]
    n = np.cross(du, dv)
    ok = (depth > 0)
    ok[:, :-1] &= depth[:, 1:] > 0
    ok[:-1] &= depth[1:] > 0
    ok[:, -1] = ok[-1] = False
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    n = np.where(ok[..., None] & (norm > 0), n / np.maximum(norm, 1e-12), 0.0)
    n *= np.where((n * P).sum(axis=-1, keepdims=True) > 0, -1.0, 1.0)  # toward the camera
    return P, n


def _consistency_scores(depth: np.ndarray, K: np.ndarray, P: np.ndarray, ts: np.ndarray, tol: float) -> np.ndarray:
    """Per candidate translation ``ts`` (M, 3): ``(explained - violations - OCCLUDED_WEIGHT occluded) / N`` of the
    camera-oriented model samples ``P`` (N, 3) placed at it (as :func:`depth_consistency`; samples off the image
    or without depth count as none)."""
    h, w = depth.shape
    Q = P[None] + ts[:, None, :]  # (M, N, 3)
    z = np.maximum(Q[..., 2], 1e-3)
    u, v = (np.rint(c).astype(np.int64) for c in pinhole_pixels(K, Q, z))
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h) & (Q[..., 2] > 1e-3)
    d = depth[np.clip(v, 0, h - 1), np.clip(u, 0, w - 1)]
    valid = inside & (d > 0)
    good = valid & (np.abs(d - z) <= tol)
    bad = valid & (d > z + tol)
    hidden = valid & (d < z - tol)
    return (good.sum(axis=1) - bad.sum(axis=1) - OCCLUDED_WEIGHT * hidden.sum(axis=1)) / max(P.shape[0], 1)


@dataclass
class _Track:
    """State of one track: the last accepted pose (4x4), the one before (for the velocity), loss frame."""

    obj_id: int
    T: np.ndarray
    T_prev: np.ndarray | None = None
    lost_at: int | None = None


class TrackICPEstimator:
    """Frame-to-frame ICP tracker initialised from the ground-truth pose of each target's first frame.

    Args:
        velocity_prior: Predict with the constant-velocity model (else from the last pose).
        max_iterations: ICP iterations per refinement.
        model_points: Surface samples per model.
        max_points: Observed points kept per target and frame (seeded subsampling).
        search_mm: Half-width of the translation search around the prediction, millimetres (0: no search).
        gate_mm: Observed points farther than this from the predicted model surface are ignored, millimetres.
        normal_deg: Observed points whose depth-image normal is farther than this from the nearest model
            sample's normal are ignored, degrees.
        consistency_mm: Depth tolerance of the loss check, millimetres.
        min_fitness: Loss when the explained fraction of the check is below this.
        min_points: Loss when fewer points are selected, or fewer samples explained.
        on_loss: ``"stop"`` or ``"retry"`` (see the module doc).
        init_rot_deg: Perturbation of the initial rotation, degrees (exact angle, random axis).
        init_trans_mm: Perturbation of the initial translation, millimetres (exact length, random direction).
        pixel_step: Use every ``pixel_step``-th pixel of the window in each direction.
        seed: Seed of the subsampling and the initial perturbation.
    """

    #: The evaluation passes each target's ground-truth pose on its first frame only (``init_poses``).
    needs_gt_init = True

    def __init__(self, velocity_prior: bool = True, max_iterations: int = 20, model_points: int = 2000,
                 max_points: int = 600, search_mm: float = 60.0, gate_mm: float = 20.0,
                 normal_deg: float = 45.0, consistency_mm: float = 10.0,
                 min_fitness: float = 0.5, min_points: int = 30, on_loss: str = "stop", init_rot_deg: float = 0.0,
                 init_trans_mm: float = 0.0, pixel_step: int = 1, seed: int = 0) -> None:
        if on_loss not in LOSS_POLICIES:
            raise ConfigError(f"track-icp: on_loss must be one of {', '.join(LOSS_POLICIES)}, got {on_loss!r}")
        check_int_options("track-icp", ("max_iterations", max_iterations, 1), ("model_points", model_points, 10),
                          ("max_points", max_points, 10), ("min_points", min_points, 3), ("pixel_step", pixel_step, 1),
                          ("seed", seed, 0))
        for name, val in (("gate_mm", gate_mm), ("consistency_mm", consistency_mm), ("normal_deg", normal_deg)):
            if not val > 0:
                raise ConfigError(f"track-icp: {name} must be > 0, got {val!r}")
        for name, val in (("init_rot_deg", init_rot_deg), ("init_trans_mm", init_trans_mm), ("search_mm", search_mm)):
            if not val >= 0:
                raise ConfigError(f"track-icp: {name} must be >= 0, got {val!r}")
        if not 0.0 <= min_fitness <= 1.0:
            raise ConfigError(f"track-icp: min_fitness must be in [0, 1], got {min_fitness!r}")
        self.velocity_prior = bool(velocity_prior)
        self.max_iterations, self.model_points, self.max_points = max_iterations, model_points, max_points
        self.gate = float(gate_mm) / 1000.0  # options in mm; metres inside
        self.search = float(search_mm) / 1000.0
        self.normal_deg = float(normal_deg)
        self.tol = float(consistency_mm) / 1000.0
        self.min_fitness, self.min_points, self.on_loss = float(min_fitness), int(min_points), on_loss
        self.init_rot = float(np.radians(init_rot_deg))
        self.init_trans = float(init_trans_mm) / 1000.0
        self.pixel_step, self.seed = int(pixel_step), int(seed)
        self.last_failures: list[dict[str, Any]] = []
        self.reset()

    def reset(self) -> None:
        """Forget every track (called by the evaluation before the first frame of each sequence)."""
        self.tracks: dict[int, _Track] = {}
        self._scene: int | None = None
        #: This frame's depth (metres) and K as float64, and its point and normal maps (set by :meth:`estimate`).
        self._frame: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None

    # --- tracks ----------------------------------------------------------------------------------------------
    def _start(self, obs: Observation, track_id: int, obj_id: int, pose: tuple[np.ndarray, np.ndarray]) -> _Track:
        """A new track at the given initial pose, perturbed as the ``init_*`` options say."""
        T = as_matrix(np.asarray(pose[0], dtype=np.float64), np.asarray(pose[1], dtype=np.float64))
        if self.init_rot > 0 or self.init_trans > 0:
            rng = np.random.default_rng([self.seed, max(obs.scene_id, 0), int(track_id)])
            T[:3, :3] = axis_angle_matrix(random_unit_vector(rng), self.init_rot) @ T[:3, :3]
            T[:3, 3] += random_unit_vector(rng) * self.init_trans
        track = _Track(int(obj_id), T)
        self.tracks[int(track_id)] = track
        return track

    def _predict(self, track: _Track) -> np.ndarray:
        T = track.T.copy()
        if self.velocity_prior and track.T_prev is not None and track.lost_at is None:
            T[:3, 3] += track.T[:3, 3] - track.T_prev[:3, 3]
        return T

    def _select(self, obs: Observation, cloud: ModelCloud, T: np.ndarray, gate: float,
                rng: np.random.Generator) -> np.ndarray:
        """Observed points (N, 3) within ``gate`` metres of the model surface at pose ``T`` (module doc, step 2)."""
        depth, K, point_map, normal_map = self._frame
        R, t = T[:3, :3], T[:3, 3]
        r = 0.5 * cloud.diameter + gate
        if t[2] <= 1e-3:
            return np.zeros((0, 3))
        u, v = pinhole_pixels(K, t)
        rad = K[0, 0] * r / max(t[2] - r, 0.05)
        h, w = depth.shape
        u0, u1 = int(max(0, np.floor(u - rad))), int(min(w, np.ceil(u + rad) + 1))
        v0, v1 = int(max(0, np.floor(v - rad))), int(min(h, np.ceil(v + rad) + 1))
        if u1 <= u0 or v1 <= v0:
            return np.zeros((0, 3))
        win = (slice(v0, v1, self.pixel_step), slice(u0, u1, self.pixel_step))
        valid = depth[win] > 0
        pts, nrm = point_map[win][valid], normal_map[win][valid]
        if len(pts):
            q = (pts - t) @ R
            idx = cloud.nearest_fast(q)
            near = cloud.surface_distance(q, fast=True) <= gate
            # Normal compatibility: the observed normal within 45 degrees of the nearest model sample's (drops
            # the supporting table around the object's base, depth edges and other surfaces).
            agree = (nrm @ R * cloud.normals[idx]).sum(axis=1) >= np.cos(np.radians(self.normal_deg))
            pts = pts[near & agree]
        if len(pts) > self.max_points:
            pts = pts[rng.choice(len(pts), self.max_points, replace=False)]
        return pts

    def _search(self, obs: Observation, cloud: ModelCloud, T: np.ndarray) -> np.ndarray:
        """The predicted pose with the translation that best explains the depth image: a grid of offsets
        (``search_mm`` wide, 9 steps per axis), then a finer grid (step / 3) around the best (module doc,
        step 2)."""
        if self.search <= 0:
            return T
        depth, K = self._frame[:2]
        R, t = T[:3, :3], T[:3, 3]
        ray = t / max(float(np.linalg.norm(t)), 1e-9)
        P = cloud.points[visible_points(cloud, (R.T @ ray)[None])[0]] @ R.T
        if len(P) > 400:
            P = P[:: int(np.ceil(len(P) / 400))]
        best, step = t.copy(), self.search / 4.0
        for _ in range(2):
            g = np.arange(-4, 5) * step if step == self.search / 4.0 else np.arange(-2, 3) * step
            offs = np.stack(np.meshgrid(g, g, g, indexing="ij"), axis=-1).reshape(-1, 3)
            scores = _consistency_scores(depth, K, P, best[None] + offs, self.tol)
            best = best + offs[int(np.argmax(scores))]
            step /= 3.0
        out = T.copy()
        out[:3, 3] = best
        return out

    # --- estimation ------------------------------------------------------------------------------------------
    def _fail(self, obs: Observation, obj_id: int, k: int, reason: str) -> None:
        log.info("track-icp: scene %d frame %d target %d (obj %d): %s", obs.scene_id, obs.frame_index, k, obj_id,
                 reason)
        self.last_failures.append({"obj_id": int(obj_id), "target_index": k, "reason": reason})

    def _lose(self, obs: Observation, track: _Track, k: int, reason: str) -> None:
        if track.lost_at is None:
            track.lost_at = obs.frame_index
        track.T_prev = None
        self._fail(obs, track.obj_id, k, f"track lost at frame {track.lost_at}: {reason}")

    def _icp(self, obs: Observation, cloud: ModelCloud, T: np.ndarray, rng: np.random.Generator
             ) -> tuple[np.ndarray, int, int] | None:
        """Two ICP rounds from ``T`` (points within ``gate_mm``, then ``gate_mm / 2``): ``(T, points,
        iterations)``, or None when too few points are selected."""
        iters, n_pts = 0, 0
        for gate in (self.gate, 0.5 * self.gate):
            pts = self._select(obs, cloud, T, gate, rng)
            n_pts = len(pts)
            if n_pts < self.min_points:
                return None
            R, t, it, _ = point_to_plane_icp(pts, cloud, T[:3, :3], T[:3, 3], self.max_iterations)
            U, _, Vt = np.linalg.svd(R)
            T = as_matrix(U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt, t)
            iters += it
        return T, n_pts, iters

    def _score(self, obs: Observation, cloud: ModelCloud, T: np.ndarray, tol: float) -> tuple[float, int, int, int]:
        """``(fitness, explained, violations, occluded)`` of pose ``T`` (module doc, step 4)."""
        e, v, o = depth_consistency(*self._frame[:2], cloud, T[:3, :3], T[:3, 3], tol)
        return e / max(e + v + OCCLUDED_WEIGHT * o, 1), e, v, o

    def _refine(self, obs: Observation, track: _Track, k: int, rng: np.random.Generator) -> PoseEstimate | None:
        """Predict, search, refine and check one track on this frame (module doc, steps 1-4)."""
        cloud = model_cloud(obs.objects.get(track.obj_id), self.model_points)
        pred = self._predict(track)
        fits = [f for f in (self._icp(obs, cloud, start, rng) for start in (pred, self._search(obs, cloud, pred)))
                if f is not None]
        if not fits:
            self._lose(obs, track, k, f"fewer than min_points={self.min_points} depth points within "
                                      f"{self.gate * 1000:.0f} mm (the gate, then half of it) of the predicted surface")
            return None
        # The start whose result fits the depth best at a tight tolerance wins.
        T, n_pts, iters = max(fits, key=lambda f: self._score(obs, cloud, f[0], 0.3 * self.tol)[0])
        fitness, explained, violations, occluded = self._score(obs, cloud, T, self.tol)
        if explained < self.min_points or fitness < self.min_fitness:
            self._lose(obs, track, k, f"fitness {fitness:.2f} (min_fitness {self.min_fitness}), {explained} model "
                                      f"samples explained by depth (min_points {self.min_points})")
            return None
        track.T_prev, track.T, track.lost_at = (track.T if track.lost_at is None else None), T, None
        return PoseEstimate(obj_id=track.obj_id, R=T[:3, :3], t=T[:3, 3], score=float(fitness), target_index=k,
                            info={"fitness": float(fitness), "explained": explained, "violations": violations,
                                  "occluded": occluded, "num_points": n_pts, "iterations": int(iters)})

    def estimate(self, observation: Observation) -> list[PoseEstimate]:
        """One estimate per tracked target that passes the loss check (see the module doc).

        Raises:
            ConfigError: The observation has no target ids, track ids or initial poses (evaluate a sequence
                dataset with ``targets='gt-masks'``; the estimator declares ``needs_gt_init``).
        """
        obs = observation
        self.last_failures = []
        if obs.target_obj_ids is None or obs.track_ids is None or obs.init_poses is None:
            raise ConfigError("track-icp: needs target ids, track ids and first-frame poses (needs_gt_init); "
                              "evaluate a sequence dataset with targets='gt-masks'")
        if obs.frame_index == 0 or obs.scene_id != self._scene:
            self.reset()
            self._scene = obs.scene_id
        rng = obs.rng(self.seed)
        depth, K = np.asarray(obs.depth, dtype=np.float64), np.asarray(obs.K, dtype=np.float64)
        self._frame = (depth, K, *point_and_normal_maps(depth, K))  # once per frame, for every track
        out = []
        for k, (obj_id, tid, init) in enumerate(zip(obs.target_obj_ids, obs.track_ids, obs.init_poses)):
            track = self._start(obs, tid, obj_id, init) if init is not None else self.tracks.get(int(tid))
            if track is None:
                self._fail(obs, int(obj_id), k, f"no initial pose for track {tid}")
                continue
            if track.lost_at is not None and self.on_loss == "stop":
                self._fail(obs, track.obj_id, k, f"track lost at frame {track.lost_at} (on_loss='stop')")
                continue
            est = self._refine(obs, track, k, rng)
            if est is not None:
                out.append(est)
        return out
