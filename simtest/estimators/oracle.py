"""The ``oracle`` estimator: ground-truth poses with controlled, seeded noise, to calibrate pipelines.

With zero noise every metric must report a perfect score; with noise the errors have a known size:

* rotation: ``R_e = Exp(angle * axis) R_g`` — a random axis (uniform on the sphere) applied in the camera
  frame. ``rot_noise_mode="halfnormal"`` (default) draws ``angle = |N(0, rot_noise_deg)|``, so the geodesic
  rotation error ``re`` is half-normal with median ``0.674 * rot_noise_deg``; ``"fixed"`` uses
  ``angle = rot_noise_deg`` exactly (``re == rot_noise_deg`` for every estimate).
* translation: ``t_e = t_g + d`` with ``d ~ N(0, sigma^2 I_3)``, ``sigma = trans_noise_mm / 1000`` metres
  (``te`` is Maxwell distributed, mean ``1.596 sigma``) in ``"halfnormal"`` mode; a uniformly random
  direction of length exactly ``trans_noise_mm`` in ``"fixed"`` mode.
* ``drop_rate``: probability of returning no estimate for a target (a miss).
* ``keypoint_noise_px``: the keypoint + PnP family's error model instead of a pose perturbation at the source:
  the object's ``keypoints`` (``"bbox"``: the 8 box corners; ``"fps"``: its farthest-point-sampled surface
  points) projected with the ground-truth pose and ``K``, each coordinate moved by ``N(0, keypoint_noise_px^2)``
  pixels, and the pose solved by EPnP + Levenberg-Marquardt, as the ``keypoints`` estimator does. It tells how
  accurate a keypoint network must be for a given score (docs/training.md); rotation and translation noise, when
  also given, apply on top. Its draws come from a stream of their own, ``default_rng([seed, scene_id, im_id,
  2])``, so the other options' draws are unchanged.

* ``error_axis`` with ``error``: one error of exact size along one axis (tolerance maps,
  ``simtest tolerance``), applied before the other noise: ``t_x``, ``t_y``, ``t_z`` move the estimate by
  ``error`` millimetres along the object's own x, y or z axis (``t_e = t_g + R_g[:, k] * d``); ``t_ray``
  moves it along the camera's viewing ray through the object's origin (a depth error); ``r_x``, ``r_y``,
  ``r_z`` rotate it by ``error`` degrees about the object's own axis through its origin
  (``R_e = R_g Exp(angle e_k)``, ``t`` unchanged). ``error_sign`` is ``"random"`` (default: +1 or -1 with
  equal probability, from a stream of its own, ``default_rng([seed, scene_id, im_id, 3, k])`` for target
  ``k``), ``"+"`` or
  ``"-"``.

The random stream is ``np.random.default_rng([seed, scene_id, im_id])``: the same seed gives the same noise
for an image however the images are ordered or split between runs.

Detection mode (``simtest eval --task detection``; the oracle declares ``needs_targets = False``, so it is
given ``gt_poses`` with their ``gt_obj_ids`` and no target ids), with options that make the AP path testable:

* ``false_positives``: the mean number (Poisson) of false positives per image: a random object of the set at a
  random rotation, 2 to 4 of its diameters away from a random target (or 0.6 m ahead without targets);
* ``duplicates``: the probability that an estimate gets a second one, 20 mm away, at 0.9 times its score;
* ``random_scores``: scores uniform in [0.5, 1] for the estimates and in [0, 1] for false positives (else 1.0
  and 0.5).

These draw from a second stream, ``default_rng([seed, scene_id, im_id, 1])``, so the estimates of the targets
are the same with and without them (the options work in localization runs too).
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from simtest.camera import pinhole_pixels
from simtest.errors import ConfigError
from simtest.estimators.base import Observation, PoseEstimate
from simtest.estimators.keypoints.infer import solve_pnp
from simtest.estimators.options import check_int_options

__all__ = ["OracleEstimator", "random_unit_vector", "axis_angle_matrix", "axis_error", "ERROR_AXES"]

_MODES = ("halfnormal", "fixed")
_KEYPOINTS = ("bbox", "fps")
#: Axes of ``error_axis``: translation along the object's x, y, z and the viewing ray; rotation about the
#: object's x, y, z.
ERROR_AXES = ("t_x", "t_y", "t_z", "t_ray", "r_x", "r_y", "r_z")
_SIGNS = ("random", "+", "-")


def random_unit_vector(rng: np.random.Generator) -> np.ndarray:
    """A direction uniform on the unit sphere (3,)."""
    v = rng.normal(size=3)
    n = float(np.linalg.norm(v))
    return v / n if n > 0 else np.array([0.0, 0.0, 1.0])


def axis_angle_matrix(axis: np.ndarray, angle: float) -> np.ndarray:
    """Rodrigues' formula: rotation by ``angle`` radians about the unit ``axis``."""
    k = np.asarray(axis, dtype=np.float64)
    Kx = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + np.sin(angle) * Kx + (1.0 - np.cos(angle)) * (Kx @ Kx)


def axis_error(R_g: np.ndarray, t_g: np.ndarray, axis: str, error: float) -> tuple[np.ndarray, np.ndarray]:
    """The pose ``(R_g, t_g)`` (camera frame, metres) moved by ``error`` along one axis of :data:`ERROR_AXES`:
    millimetres for the ``t_*`` axes, degrees for the ``r_*`` axes (signed; see the module doc).

    Raises:
        ConfigError: ``axis`` is not one of :data:`ERROR_AXES`.
    """
    R_g, t_g = np.asarray(R_g, dtype=np.float64), np.asarray(t_g, dtype=np.float64)
    if axis not in ERROR_AXES:
        raise ConfigError(f"oracle: error_axis must be one of {', '.join(ERROR_AXES)} or none, got {axis!r}")
    if axis == "t_ray":
        n = float(np.linalg.norm(t_g))
        ray = t_g / n if n > 0 else np.array([0.0, 0.0, 1.0])
        return R_g.copy(), t_g + ray * error / 1000.0
    k = "xyz".index(axis[-1])
    if axis.startswith("t_"):
        return R_g.copy(), t_g + R_g[:, k] * error / 1000.0
    return R_g @ axis_angle_matrix(np.eye(3)[k], float(np.radians(error))), t_g.copy()


class OracleEstimator:
    """Ground truth plus noise (see the module doc for the noise model).

    Args:
        rot_noise_deg: Rotation noise, degrees: the standard deviation of the half-normal angle, or the exact
            angle in ``"fixed"`` mode.
        trans_noise_mm: Translation noise, millimetres: the per-axis standard deviation, or the exact offset
            length in ``"fixed"`` mode.
        seed: Seed of the noise (combined with scene and image ids).
        drop_rate: Probability in [0, 1] of giving no estimate for a target.
        rot_noise_mode: ``"halfnormal"`` or ``"fixed"`` (applies to both rotation and translation).
        false_positives: Mean number of false positives per image (Poisson), >= 0.
        duplicates: Probability in [0, 1] of a second estimate beside an estimate.
        random_scores: Random scores instead of constant ones (see the module doc).
        keypoint_noise_px: Standard deviation (pixels) of the noise on projected ground-truth keypoints, whose
            PnP solution then replaces the ground-truth pose; 0 (default) leaves the pose exact.
        keypoints: The keypoints of ``keypoint_noise_px``: ``"bbox"`` (default) or ``"fps"``.
        error_axis: ``"none"`` (default) or one of :data:`ERROR_AXES`: the axis of an exact error ``error``.
        error: Size of that error: millimetres (``t_*`` axes) or degrees (``r_*`` axes), >= 0.
        error_sign: ``"random"`` (default), ``"+"`` or ``"-"``: the sign of that error.

    Attributes:
        needs_gt: Always True: the evaluation passes ground-truth poses in ``Observation.gt_poses``.
        needs_targets: False: in the detection task it runs from ``gt_poses`` and ``gt_obj_ids``.
        needs_depth: False: it reads no image at all.
    """

    needs_gt = True
    needs_targets = False
    needs_depth = False

    def __init__(self, rot_noise_deg: float = 0.0, trans_noise_mm: float = 0.0, seed: int = 0,
                 drop_rate: float = 0.0, rot_noise_mode: str = "halfnormal", false_positives: float = 0.0,
                 duplicates: float = 0.0, random_scores: bool = False, keypoint_noise_px: float = 0.0,
                 keypoints: str = "bbox", error_axis: str = "none", error: float = 0.0,
                 error_sign: str = "random") -> None:
        if not rot_noise_deg >= 0:
            raise ConfigError(f"oracle: rot_noise_deg must be >= 0 degrees, got {rot_noise_deg!r}")
        if not trans_noise_mm >= 0:
            raise ConfigError(f"oracle: trans_noise_mm must be >= 0 millimetres, got {trans_noise_mm!r}")
        if not 0.0 <= drop_rate <= 1.0:
            raise ConfigError(f"oracle: drop_rate must be in [0, 1], got {drop_rate!r}")
        if rot_noise_mode not in _MODES:
            raise ConfigError(f"oracle: rot_noise_mode must be one of {', '.join(_MODES)}, got {rot_noise_mode!r}")
        if not false_positives >= 0:
            raise ConfigError(f"oracle: false_positives must be >= 0 per image, got {false_positives!r}")
        if not 0.0 <= duplicates <= 1.0:
            raise ConfigError(f"oracle: duplicates must be in [0, 1], got {duplicates!r}")
        if not keypoint_noise_px >= 0:
            raise ConfigError(f"oracle: keypoint_noise_px must be >= 0 pixels, got {keypoint_noise_px!r}")
        if keypoints not in _KEYPOINTS:
            raise ConfigError(f"oracle: keypoints must be one of {', '.join(_KEYPOINTS)}, got {keypoints!r}")
        if error_axis != "none" and error_axis not in ERROR_AXES:
            raise ConfigError(f"oracle: error_axis must be one of none, {', '.join(ERROR_AXES)}, got {error_axis!r}")
        if not error >= 0:
            raise ConfigError(f"oracle: error must be >= 0 (mm for t_* axes, degrees for r_* axes), got {error!r}")
        if error_sign not in _SIGNS:
            raise ConfigError(f"oracle: error_sign must be one of {', '.join(_SIGNS)}, got {error_sign!r}")
        check_int_options("oracle", ("seed", seed, 0))
        self.error_axis, self.error, self.error_sign = error_axis, float(error), error_sign
        self.keypoint_noise, self.keypoints = float(keypoint_noise_px), keypoints
        self.false_positives, self.duplicates = float(false_positives), float(duplicates)
        self.random_scores = bool(random_scores)
        self.rot_noise = float(np.radians(rot_noise_deg))
        self.trans_noise = float(trans_noise_mm) / 1000.0  # option given in mm; metres inside
        self.seed = int(seed)
        self.drop_rate = float(drop_rate)
        self.mode = rot_noise_mode

    def __repr__(self) -> str:
        return (f"OracleEstimator(rot_noise_deg={np.degrees(self.rot_noise):g}, "
                f"trans_noise_mm={self.trans_noise * 1000:g}, seed={self.seed}, drop_rate={self.drop_rate:g}, "
                f"rot_noise_mode={self.mode!r}, false_positives={self.false_positives:g}, "
                f"duplicates={self.duplicates:g}, random_scores={self.random_scores}, "
                f"keypoint_noise_px={self.keypoint_noise:g}, keypoints={self.keypoints!r}"
                + (f", error_axis={self.error_axis!r}, error={self.error:g}, error_sign={self.error_sign!r}"
                   if self.error_axis != "none" else "") + ")")

    def estimate(self, observation: Observation) -> list[PoseEstimate]:
        """One estimate per target, from ``observation.gt_poses`` (and the extras of the module doc).

        Raises:
            ConfigError: The observation carries no ground-truth poses or object ids.
        """
        ids = observation.target_obj_ids if observation.target_obj_ids is not None else observation.gt_obj_ids
        if observation.gt_poses is None or ids is None:
            raise ConfigError("oracle: the observation has no gt_poses / target_obj_ids; evaluate with "
                              "targets='gt-masks' (the oracle needs ground-truth targets)")
        rng = observation.rng(self.seed)
        kp_rng = np.random.default_rng([self.seed, max(observation.scene_id, 0), max(observation.im_id, 0), 2]) \
            if self.keypoint_noise > 0 else None
        out = []
        for k, (obj_id, (R_g, t_g)) in enumerate(zip(ids, observation.gt_poses)):
            # Draw every number whether or not it is used, so options do not shift the stream.
            drop = rng.random() < self.drop_rate
            axis, u_rot = random_unit_vector(rng), rng.normal()
            d_dir, d_gauss = random_unit_vector(rng), rng.normal(size=3)
            info: dict = {}
            if kp_rng is not None:
                R_g, t_g, info = self._keypoint_pose(observation, int(obj_id), R_g, t_g, kp_rng)
            if drop or R_g is None:
                continue
            if self.error_axis != "none":
                signed = self._signed_error(observation, k)
                R_g, t_g = axis_error(R_g, t_g, self.error_axis, signed)
                info["axis_error"] = signed
            if self.mode == "fixed":
                angle, dt = self.rot_noise, d_dir * self.trans_noise
            else:
                angle, dt = abs(u_rot) * self.rot_noise, d_gauss * self.trans_noise
            R = axis_angle_matrix(axis, angle) @ np.asarray(R_g, dtype=np.float64)
            t = np.asarray(t_g, dtype=np.float64) + dt
            out.append(PoseEstimate(obj_id=int(obj_id), R=R, t=t, score=1.0, target_index=k,
                                    info={"rot_noise_rad": float(angle), "trans_noise_m": float(np.linalg.norm(dt)),
                                          **info}))
        if self.false_positives or self.duplicates or self.random_scores:
            out = self._extras(observation, out)
        return out

    def _signed_error(self, obs: Observation, k: int) -> float:
        """``error`` with its sign for target ``k`` (see ``error_sign``)."""
        if self.error_sign != "random":
            return self.error if self.error_sign == "+" else -self.error
        rng = np.random.default_rng([self.seed, max(obs.scene_id, 0), max(obs.im_id, 0), 3, k])
        return self.error if rng.random() < 0.5 else -self.error

    def _keypoint_pose(self, obs: Observation, obj_id: int, R_g, t_g, rng: np.random.Generator):
        """``(R, t, info)`` solved by PnP from the ground-truth keypoints projected with ``obs.K`` plus noise
        (``R`` None when PnP fails: no estimate, as a real keypoint pipeline would give none)."""
        obj = obs.objects.get(obj_id)
        kp3 = np.asarray(obj.keypoints_bbox if self.keypoints == "bbox" else obj.keypoints_fps, dtype=np.float64)
        cam = kp3 @ np.asarray(R_g, dtype=np.float64).T + np.asarray(t_g, dtype=np.float64)
        uv = np.stack(pinhole_pixels(np.asarray(obs.K, dtype=np.float64), cam), axis=1)
        uv += rng.normal(0.0, self.keypoint_noise, size=uv.shape)
        try:
            R, t, rms = solve_pnp(uv, kp3, obs.K)
        except ValueError:
            return None, None, {}
        return R, t, {"keypoint_noise_px": self.keypoint_noise, "pnp_rms_px": float(rms)}

    def _extras(self, obs: Observation, out: list[PoseEstimate]) -> list[PoseEstimate]:
        """``out`` with random scores, duplicates and false positives (see the module doc), from the second
        stream."""
        rng = np.random.default_rng([self.seed, max(obs.scene_id, 0), max(obs.im_id, 0), 1])
        extra: list[PoseEstimate] = []
        for i, e in enumerate(out):
            score = float(rng.uniform(0.5, 1.0)) if self.random_scores else e.score
            out[i] = e = replace(e, score=score)
            if rng.random() < self.duplicates:
                extra.append(replace(e, t=e.t + random_unit_vector(rng) * 0.02, score=0.9 * score,
                                     info={**e.info, "duplicate": True}))
        ids = list(obs.objects.ids)
        for _ in range(int(rng.poisson(self.false_positives)) if self.false_positives else 0):
            obj_id = int(ids[rng.integers(len(ids))])
            R = axis_angle_matrix(random_unit_vector(rng), float(rng.uniform(0, np.pi)))
            diameter = float(obs.objects.get(obj_id).diameter)
            base = (np.asarray(obs.gt_poses[rng.integers(len(obs.gt_poses))][1], np.float64) if obs.gt_poses
                    else np.array([0.0, 0.0, 0.6]))
            t = base + random_unit_vector(rng) * diameter * float(rng.uniform(2.0, 4.0))
            extra.append(PoseEstimate(obj_id=obj_id, R=R, t=t, score=float(rng.random()) if self.random_scores
                                      else 0.5, info={"false_positive": True}))
        return out + extra
