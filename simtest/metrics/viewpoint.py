"""Viewpoint-estimation protocol (PASCAL3D+ / ObjectNet3D style, as used by NeMo): geodesic rotation error,
accuracy at pi/6 and pi/18, median error; and the (azimuth, elevation, in-plane theta) parameterisation.

Angles are radians unless a name says degrees.

Viewpoint convention (object frame Z up, as BOP / simtest models; camera frame OpenCV x right, y down,
z forward; ``R`` maps object coordinates into the camera frame, ``x_c = R x_o + t``):

* The camera looks at the object origin from the unit direction (object frame, origin -> camera)
  ``d = (cos(el) sin(az), -cos(el) cos(az), sin(el))`` — the camera-centre formula of PASCAL3D+ / NeMo.
  So azimuth 0 puts the camera on the object's -Y side, azimuth pi/2 on its +X side (azimuth grows
  counter-clockwise seen from above, i.e. right-handed about +Z), and positive elevation is above the
  XY plane (looking down).
* With ``theta = 0`` the camera is upright: its x axis is horizontal (``x = normalize(f x Z)`` with
  ``f = -d`` the viewing direction) and the object's +Z projects upwards in the image.
* ``theta`` rotates the camera frame about its optical axis: ``R = Rz(theta) R0(az, el)`` with
  ``Rz(theta) = [[c, -s, 0], [s, c, 0], [0, 0, 1]]``; positive theta turns the object's image clockwise
  on screen (y points down).
* At ``el = +-pi/2`` the azimuth is undefined; the decomposition returns ``az = 0`` and puts all of the
  in-plane rotation into ``theta``.

The conversion uses the rotation only (the viewing direction is the camera's optical axis); the translation
is ``(0, 0, distance)`` in :func:`viewpoint_to_pose` (object on the optical axis).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from simtest.errors import ConfigError

__all__ = [
    "geodesic_error",
    "rotation_errors",
    "accuracy_at",
    "median_error_deg",
    "viewpoint_summary",
    "viewpoint_to_rotation",
    "rotation_to_viewpoint",
    "viewpoint_to_pose",
    "pose_to_viewpoint",
    "classification_accuracy",
    "PI_6",
    "PI_18",
]

PI_6 = np.pi / 6.0
PI_18 = np.pi / 18.0


def geodesic_error(R_p: np.ndarray, R_gt: np.ndarray) -> np.ndarray | float:
    """Geodesic rotation error ``|| logm(R_p^T R_gt) ||_F / sqrt(2)``, radians in [0, pi].

    Computed as ``arccos(clip((trace(R_p^T R_gt) - 1) / 2, -1, 1))``. Broadcasts over leading dimensions.

    Args:
        R_p: Predicted rotation(s) (..., 3, 3).
        R_gt: Ground-truth rotation(s) (..., 3, 3).

    Returns:
        Angle(s) in radians; a float for single matrices.
    """
    R_p = np.asarray(R_p, dtype=np.float64)
    R_gt = np.asarray(R_gt, dtype=np.float64)
    if R_p.shape[-2:] != (3, 3) or R_gt.shape[-2:] != (3, 3):
        raise ConfigError(f"rotations must be (..., 3, 3), got {R_p.shape} and {R_gt.shape}")
    tr = np.einsum("...ij,...ij->...", R_p, R_gt)  # trace(R_p^T R_gt)
    err = np.arccos(np.clip(0.5 * (tr - 1.0), -1.0, 1.0))
    return float(err) if np.ndim(err) == 0 else err


def rotation_errors(preds: Sequence[np.ndarray | None], gts: Sequence[np.ndarray]) -> np.ndarray:
    """Per-sample geodesic errors (radians); a missing prediction (``None``) scores ``pi``.

    Args:
        preds: Predicted 3x3 rotations, ``None`` where the method gave no prediction.
        gts: Ground-truth 3x3 rotations, same length.

    Returns:
        Errors (N,), radians in [0, pi].
    """
    if len(preds) != len(gts):
        raise ConfigError(f"got {len(preds)} predictions for {len(gts)} ground-truth rotations")
    out = np.full(len(gts), np.pi)
    have = [i for i, p in enumerate(preds) if p is not None]
    if have:
        P = np.stack([np.asarray(preds[i], dtype=np.float64) for i in have])
        G = np.stack([np.asarray(gts[i], dtype=np.float64) for i in have])
        out[have] = geodesic_error(P, G)
    return out


def _errors(errors: Sequence[float | None] | np.ndarray) -> np.ndarray:
    e = np.array([np.pi if x is None else x for x in errors], dtype=np.float64) if not isinstance(
        errors, np.ndarray) else errors.astype(np.float64).reshape(-1)
    if len(e) == 0:
        raise ConfigError("errors must not be empty")
    e = np.where(np.isnan(e), np.pi, e)
    if np.any(e < 0):
        raise ConfigError(f"rotation errors must be >= 0 radians, got {e[e < 0][:10].tolist()}")
    return e


def accuracy_at(errors: Sequence[float | None] | np.ndarray, threshold: float = PI_6) -> float:
    """Fraction of errors ``< threshold`` (radians; the protocol uses pi/6 and pi/18).

    ``None`` or NaN errors (missing predictions) count as ``pi``.
    """
    if not threshold > 0:
        raise ConfigError(f"threshold must be > 0 radians, got {threshold!r}")
    return float(np.mean(_errors(errors) < threshold))


def median_error_deg(errors: Sequence[float | None] | np.ndarray) -> float:
    """Median of the errors in degrees (input radians; ``None`` / NaN count as ``pi``)."""
    return float(np.degrees(np.median(_errors(errors))))


def viewpoint_summary(errors: Sequence[float | None] | np.ndarray) -> dict[str, float]:
    """``{"acc_pi_6", "acc_pi_18", "median_deg"}`` for rotation errors in radians (missing = pi)."""
    e = _errors(errors)
    return {"acc_pi_6": accuracy_at(e, PI_6), "acc_pi_18": accuracy_at(e, PI_18), "median_deg": median_error_deg(e)}


def classification_accuracy(pred_labels: Sequence, gt_labels: Sequence) -> float:
    """Fraction of correct class labels (reported beside the viewpoint accuracy)."""
    if len(pred_labels) != len(gt_labels) or len(gt_labels) == 0:
        raise ConfigError(f"need equally many, non-zero labels, got {len(pred_labels)} and {len(gt_labels)}")
    return float(np.mean([p == g for p, g in zip(pred_labels, gt_labels)]))


def _rz(theta: float) -> np.ndarray:
    c, s = np.cos(theta), np.sin(theta)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def viewpoint_to_rotation(azimuth: float, elevation: float, theta: float) -> np.ndarray:
    """Camera-frame rotation ``R`` (object -> OpenCV camera) of a viewpoint; see the module convention.

    Args:
        azimuth: Radians; 0 = camera on the object's -Y side, pi/2 = on its +X side.
        elevation: Radians in [-pi/2, pi/2]; positive = camera above the object's XY plane.
        theta: In-plane rotation about the optical axis, radians (positive = clockwise on screen).

    Returns:
        3x3 rotation matrix.
    """
    if not -np.pi / 2 - 1e-12 <= elevation <= np.pi / 2 + 1e-12:
        raise ConfigError(f"elevation must be in [-pi/2, pi/2] radians, got {elevation!r}")
    ca, sa, ce, se = np.cos(azimuth), np.sin(azimuth), np.cos(elevation), np.sin(elevation)
    f = -np.array([ce * sa, -ce * ca, se])  # viewing direction (camera z), object frame
    # Horizontal right vector: f x Z normalised; equals (cos az, sin az, 0) for ce > 0, and is taken so at
    # the poles too (continuous in azimuth).
    x = np.array([ca, sa, 0.0])
    y = np.cross(f, x)
    R0 = np.stack([x, y, f])  # rows: camera axes in object coordinates
    return _rz(theta) @ R0


def rotation_to_viewpoint(R: np.ndarray) -> tuple[float, float, float]:
    """Decompose a camera-frame rotation into ``(azimuth, elevation, theta)``, radians.

    Inverse of :func:`viewpoint_to_rotation` (azimuth and theta in (-pi, pi], elevation in [-pi/2, pi/2];
    at the poles azimuth is returned as 0).
    """
    R = np.asarray(R, dtype=np.float64)
    if R.shape != (3, 3):
        raise ConfigError(f"R must be 3x3, got shape {R.shape}")
    d = -R[2]  # origin -> camera direction in object coordinates
    el = float(np.arcsin(np.clip(d[2], -1.0, 1.0)))
    if np.hypot(d[0], d[1]) < 1e-9:
        az = 0.0
    else:
        az = float(np.arctan2(d[0], -d[1]))
    M = R @ viewpoint_to_rotation(az, el, 0.0).T  # = Rz(theta)
    theta = float(np.arctan2(M[1, 0], M[0, 0]))
    return az, el, theta


def viewpoint_to_pose(azimuth: float, elevation: float, theta: float, distance: float
                      ) -> tuple[np.ndarray, np.ndarray]:
    """Camera-frame pose ``(R, t)`` of a viewpoint at ``distance`` metres, object on the optical axis."""
    if not distance > 0:
        raise ConfigError(f"distance must be > 0 metres, got {distance!r}")
    return viewpoint_to_rotation(azimuth, elevation, theta), np.array([0.0, 0.0, float(distance)])


def pose_to_viewpoint(R: np.ndarray, t: np.ndarray) -> tuple[float, float, float, float]:
    """``(azimuth, elevation, theta, distance)`` of a camera-frame pose (radians, metres).

    The angles come from the rotation (:func:`rotation_to_viewpoint`); ``distance = ||t||``.
    """
    return (*rotation_to_viewpoint(R), float(np.linalg.norm(np.asarray(t, dtype=np.float64))))
