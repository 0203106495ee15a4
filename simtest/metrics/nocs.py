"""Category-level pose metrics (NOCS protocol, Wang et al. 2019) and the Chamfer distance.

Poses are similarity transforms ``sRT`` (4x4: ``[[s R, t], [0, 1]]``, ``t`` in metres) mapping the
canonical (normalised) object frame into the camera frame; boxes are the canonical boxes of extents
``size`` (3,) centred at the canonical origin, so their metric extents are ``s * size``.

Symmetric categories: the NOCS reference treats bottle, bowl and can (and mug when its handle is not
visible) as symmetric about the canonical *y* axis (NOCS models are Y-up). simtest models are Z-up (BOP),
so every function here takes the symmetry axis as a parameter that defaults to ``z``; pass
``sym_axis=(0, 1, 0)`` to reproduce numbers on NOCS-frame data.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence

import numpy as np
from scipy.spatial import ConvexHull, QhullError, cKDTree

from simtest.errors import ConfigError
from simtest.geometry import rotation_about

__all__ = [
    "SYMMETRIC_CATEGORIES",
    "NOCS_THRESHOLDS",
    "IOU_THRESHOLDS",
    "remove_scale",
    "rotation_error",
    "rotation_error_deg",
    "translation_error_cm",
    "n_deg_m_cm",
    "n_deg_m_cm_accuracy",
    "box_corners",
    "iou_3d",
    "iou_3d_legacy",
    "iou_accuracy",
    "is_symmetric_category",
    "chamfer_distance",
]

#: Categories the NOCS reference evaluates as rotationally symmetric (mug too when the handle is hidden).
SYMMETRIC_CATEGORIES = ("bottle", "bowl", "can")
#: The (degrees, centimetres) pairs of the n deg m cm accuracy.
NOCS_THRESHOLDS: tuple[tuple[float, float], ...] = ((5, 2), (5, 5), (10, 2), (10, 5))
#: 3D IoU thresholds of the protocol.
IOU_THRESHOLDS = (0.25, 0.50, 0.75)
#: Number of rotations about the symmetry axis over which the IoU of a symmetric category is maximised.
IOU_SYM_STEPS = 20

_Z = (0.0, 0.0, 1.0)


def is_symmetric_category(category: str, handle_visible: bool = True) -> bool:
    """Whether the NOCS protocol treats ``category`` as symmetric (mug only when its handle is hidden)."""
    return category in SYMMETRIC_CATEGORIES or (category == "mug" and not handle_visible)


def _mat(T: np.ndarray, name: str) -> np.ndarray:
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (4, 4):
        raise ConfigError(f"{name} must be a 4x4 similarity transform, got shape {T.shape}")
    return T


def _axis(axis: Sequence[float]) -> np.ndarray:
    a = np.asarray(axis, dtype=np.float64).reshape(-1)
    n = np.linalg.norm(a)
    if a.shape != (3,) or not n > 0:
        raise ConfigError(f"sym_axis must be a non-zero 3-vector, got {axis!r}")
    return a / n


def remove_scale(sR: np.ndarray) -> np.ndarray:
    """``sR / cbrt(det(sR))``: the rotation of a uniformly scaled rotation (3x3)."""
    sR = np.asarray(sR, dtype=np.float64)
    if sR.shape != (3, 3):
        raise ConfigError(f"expected a 3x3 scaled rotation, got shape {sR.shape}")
    det = np.linalg.det(sR)
    if not det > 0:
        raise ConfigError(f"scaled rotation must have det > 0, got {det!r}")
    return sR / np.cbrt(det)


def rotation_error(sR_1: np.ndarray, sR_2: np.ndarray, symmetric: bool = False,
                   sym_axis: Sequence[float] = _Z) -> float:
    """Rotation error of the NOCS protocol, radians in [0, pi].

    Scale is removed from both (``R / cbrt(det R)``). Asymmetric: ``arccos((trace(R_1 R_2^T) - 1) / 2)``.
    Symmetric: the angle between the two images of the symmetry axis, ``arccos((R_1 a) . (R_2 a))`` (the
    reference uses the y axis; simtest's Z-up models use z, the default). Arguments are clipped to
    [-1, 1] (the reference does not clip and can return NaN).

    Args:
        sR_1: 3x3 (scaled) rotation, or a 4x4 sRT whose upper-left block is used.
        sR_2: Same for the other pose.
        symmetric: Use the symmetry-axis angle.
        sym_axis: Symmetry axis in the canonical frame.

    Returns:
        Error in radians.
    """
    R1 = remove_scale(np.asarray(sR_1, dtype=np.float64)[:3, :3])
    R2 = remove_scale(np.asarray(sR_2, dtype=np.float64)[:3, :3])
    if symmetric:
        a = _axis(sym_axis)
        a1, a2 = R1 @ a, R2 @ a
        cos = float(a1 @ a2 / (np.linalg.norm(a1) * np.linalg.norm(a2)))
    else:
        cos = 0.5 * (float(np.trace(R1 @ R2.T)) - 1.0)
    return float(np.arccos(np.clip(cos, -1.0, 1.0)))


def rotation_error_deg(sR_1: np.ndarray, sR_2: np.ndarray, symmetric: bool = False,
                       sym_axis: Sequence[float] = _Z) -> float:
    """:func:`rotation_error` in degrees (the unit of the NOCS tables)."""
    return float(np.degrees(rotation_error(sR_1, sR_2, symmetric, sym_axis)))


def translation_error_cm(t_1: np.ndarray, t_2: np.ndarray) -> float:
    """``|| t_1 - t_2 ||`` in centimetres, for translations given in metres (3-vectors or 4x4 sRT)."""
    a = np.asarray(t_1, dtype=np.float64)
    b = np.asarray(t_2, dtype=np.float64)
    a = a[:3, 3] if a.shape == (4, 4) else a.reshape(-1)
    b = b[:3, 3] if b.shape == (4, 4) else b.reshape(-1)
    if a.shape != (3,) or b.shape != (3,):
        raise ConfigError(f"translations must be 3-vectors (metres) or 4x4 sRT, got {np.shape(t_1)}, {np.shape(t_2)}")
    return float(np.linalg.norm(a - b) * 100.0)


def n_deg_m_cm(rot_err_deg: float, trans_err_cm: float, n_deg: float, m_cm: float) -> bool:
    """Whether a pose is within ``n`` degrees and ``m`` centimetres; both bounds inclusive (``<=``)."""
    return bool(rot_err_deg <= n_deg and trans_err_cm <= m_cm)


def n_deg_m_cm_accuracy(rot_errs_deg: Iterable[float], trans_errs_cm: Iterable[float],
                        thresholds: Sequence[tuple[float, float]] = NOCS_THRESHOLDS) -> dict[str, float]:
    """Fraction of poses within each ``(n degrees, m centimetres)`` pair, inclusive.

    Args:
        rot_errs_deg: Rotation errors, degrees (NaN counts as a failure).
        trans_errs_cm: Translation errors, centimetres.
        thresholds: ``(n, m)`` pairs; default (5, 2), (5, 5), (10, 2), (10, 5).

    Returns:
        ``{"5deg2cm": ..., ...}`` fractions in [0, 1].
    """
    r = np.asarray(list(rot_errs_deg), dtype=np.float64)
    t = np.asarray(list(trans_errs_cm), dtype=np.float64)
    if r.shape != t.shape or r.size == 0:
        raise ConfigError(f"need equally many, non-zero errors, got {r.size} rotation and {t.size} translation")
    return {f"{n:g}deg{m:g}cm": float(np.mean((r <= n) & (t <= m))) for n, m in thresholds}


# --- 3D boxes -------------------------------------------------------------------------------------------

def _size(size: Sequence[float], name: str) -> np.ndarray:
    s = np.asarray(size, dtype=np.float64).reshape(-1)
    if s.shape != (3,) or not np.all(s > 0):
        raise ConfigError(f"{name} must be 3 positive box extents, got {size!r}")
    return s


def box_corners(size: Sequence[float]) -> np.ndarray:
    """The 8 corners (8, 3) of a box of extents ``size`` centred at the origin, in the NOCS reference order
    (``get_3d_bbox``: x, y, z signs ``+++, ++-, -++, -+-, +-+, +--, --+, ---``)."""
    s = _size(size, "size")
    signs = np.array([[1, 1, 1], [1, 1, -1], [-1, 1, 1], [-1, 1, -1],
                      [1, -1, 1], [1, -1, -1], [-1, -1, 1], [-1, -1, -1]], dtype=np.float64)
    return signs * s / 2.0


#: The 12 box edges as corner-index pairs, corners indexed by bits (bit k set = + along axis k).
_BIT_EDGES = np.array([(i, i | (1 << k)) for i in range(8) for k in range(3) if not i & (1 << k)])


def _box_geometry(T: np.ndarray, size: np.ndarray):
    """Corners (8, 3), edges (12, 2, 3), face half-spaces (6, 4) ``n.x + d <= 0`` and volume of a posed box."""
    half = size / 2.0
    # Corners indexed by bits (bit k set = + along axis k) so that edges join indices differing by one bit.
    bits = np.array([[(i >> k) & 1 for k in range(3)] for i in range(8)], dtype=np.float64)
    local = (2.0 * bits - 1.0) * half
    A, b = T[:3, :3], T[:3, 3]
    corners = local @ A.T + b
    edges = np.stack([corners[_BIT_EDGES[:, 0]], corners[_BIT_EDGES[:, 1]]], axis=1)
    # Faces: in the local frame |x_k| <= half_k. Map the planes with the inverse-transpose of A.
    Ainv = np.linalg.inv(A)
    planes = []
    for k in range(3):
        for sgn in (1.0, -1.0):
            n_local = np.zeros(3)
            n_local[k] = sgn
            # Local constraint: sgn x_k - half_k <= 0 with x = Ainv (p - b).
            n = Ainv.T @ n_local
            d = -n @ b - half[k]
            scale = np.linalg.norm(n)
            planes.append(np.concatenate([n, [d]]) / scale)
    volume = abs(np.linalg.det(A)) * float(np.prod(size))
    return corners, edges, np.array(planes), volume



def _clip_segments(edges: np.ndarray, planes: np.ndarray, tol: float) -> np.ndarray:
    """Points where the segments (E, 2, 3) cross the planes (P, 4), kept only if inside all planes."""
    p0, p1 = edges[:, 0], edges[:, 1]
    s0 = p0 @ planes[:, :3].T + planes[:, 3]  # (E, P)
    s1 = p1 @ planes[:, :3].T + planes[:, 3]
    cross = (s0 * s1) < 0
    with np.errstate(divide="ignore", invalid="ignore"):
        lam = s0 / (s0 - s1)
    e_idx, p_idx = np.nonzero(cross)
    pts = p0[e_idx] + lam[e_idx, p_idx, None] * (p1[e_idx] - p0[e_idx])
    if len(pts) == 0:
        return pts
    inside = np.all(pts @ planes[:, :3].T + planes[:, 3] <= tol, axis=1)
    return pts[inside]


def _intersection_volume(T1: np.ndarray, size1: np.ndarray, T2: np.ndarray, size2: np.ndarray
                         ) -> tuple[float, float, float]:
    """Intersection volume and the two box volumes (cubic metres)."""
    c1, e1, h1, v1 = _box_geometry(T1, size1)
    c2, e2, h2, v2 = _box_geometry(T2, size2)
    tol = 1e-9 * max(np.ptp(np.vstack([c1, c2]), axis=0).max(), 1e-12)
    pts = [c1[np.all(c1 @ h2[:, :3].T + h2[:, 3] <= tol, axis=1)],
           c2[np.all(c2 @ h1[:, :3].T + h1[:, 3] <= tol, axis=1)],
           _clip_segments(e1, h2, tol), _clip_segments(e2, h1, tol)]
    pts = np.vstack(pts)
    if len(pts) < 4:
        return 0.0, v1, v2
    centred = pts - pts.mean(axis=0)
    if np.linalg.matrix_rank(centred, tol=tol) < 3:
        return 0.0, v1, v2
    try:
        inter = float(ConvexHull(pts).volume)
    except QhullError:
        return 0.0, v1, v2
    return min(inter, v1, v2), v1, v2


def _iou_pair(T1: np.ndarray, size1: np.ndarray, T2: np.ndarray, size2: np.ndarray) -> float:
    inter, v1, v2 = _intersection_volume(T1, size1, T2, size2)
    union = v1 + v2 - inter
    return float(inter / union) if union > 0 else 0.0


def _sym_rotations(sym_axis: Sequence[float], steps: int) -> list[np.ndarray]:
    a = _axis(sym_axis)
    out = []
    for i in range(steps):
        T = np.eye(4)
        T[:3, :3] = rotation_about(a, 2.0 * np.pi * i / steps)
        out.append(T)
    return out


def iou_3d(sRT_1: np.ndarray, sRT_2: np.ndarray, size_1: Sequence[float], size_2: Sequence[float],
           symmetric: bool = False, sym_axis: Sequence[float] = _Z, sym_steps: int = IOU_SYM_STEPS) -> float:
    """Exact 3D IoU of two oriented boxes.

    Each box is the canonical box of extents ``size`` mapped by its 4x4 transform (any invertible affine map,
    so also non-uniform scale). The intersection of two convex polytopes is the convex hull of: the corners
    of each box inside the other, and the crossings of each box's edges with the other's faces; its volume
    comes from ``scipy.spatial.ConvexHull``. For a symmetric category the IoU is maximised over
    ``sym_steps`` rotations of box 1 by ``2 pi i / sym_steps`` about ``sym_axis`` in its canonical frame
    (``sRT_1 @ Rot(axis, angle)``, as the NOCS reference does about y).

    Args:
        sRT_1: 4x4 similarity transform (canonical -> camera, metres).
        sRT_2: 4x4 similarity transform.
        size_1: Canonical box extents (3,) of box 1 (metres after scaling by ``s``).
        size_2: Canonical box extents (3,) of box 2.
        symmetric: Maximise over rotations about ``sym_axis``.
        sym_axis: Symmetry axis in the canonical frame (default z; the NOCS reference uses y).
        sym_steps: Number of rotations (20 in the reference).

    Returns:
        IoU in [0, 1].
    """
    T1, T2 = _mat(sRT_1, "sRT_1"), _mat(sRT_2, "sRT_2")
    s1, s2 = _size(size_1, "size_1"), _size(size_2, "size_2")
    for name, T in (("sRT_1", T1), ("sRT_2", T2)):
        if not abs(np.linalg.det(T[:3, :3])) > 0:
            raise ConfigError(f"{name} has a singular linear part: {T[:3, :3].tolist()}")
    if not symmetric:
        return _iou_pair(T1, s1, T2, s2)
    return max(_iou_pair(T1 @ Rs, s1, T2, s2) for Rs in _sym_rotations(sym_axis, sym_steps))


def iou_3d_legacy(sRT_1: np.ndarray, sRT_2: np.ndarray, size_1: Sequence[float], size_2: Sequence[float],
                  symmetric: bool = False, sym_axis: Sequence[float] = (0.0, 1.0, 0.0),
                  sym_steps: int = IOU_SYM_STEPS) -> float:
    """The NOCS reference's 3D IoU (``compute_3d_iou_new`` / ``asymmetric_3d_iou``), reproduced with its bug.

    Only for comparing with numbers published with that code; use :func:`iou_3d` otherwise. The reference
    stores the transformed corners as a (3, 8) array and takes ``amax`` / ``amin`` over axis 0, i.e. over
    x/y/z per corner instead of over the corners per axis, then multiplies the eight resulting "extents".
    The value depends on where the boxes sit: two 10 cm cubes 0.7 m in front of the camera, 2 cm apart
    along x, give 0.947 instead of the true 0.667. Symmetric categories are maximised over ``sym_steps``
    rotations about ``sym_axis`` (default y, as the reference).

    Args:
        sRT_1: 4x4 similarity transform (canonical -> camera, metres).
        sRT_2: 4x4 similarity transform.
        size_1: Canonical box extents (3,).
        size_2: Canonical box extents (3,).
        symmetric: Maximise over rotations about ``sym_axis``.
        sym_axis: Symmetry axis (the reference: y).
        sym_steps: Number of rotations (the reference: 20).

    Returns:
        The reference's (incorrect) IoU; NaN where the reference divides 0 by 0.
    """
    T1, T2 = _mat(sRT_1, "sRT_1"), _mat(sRT_2, "sRT_2")
    c1, c2 = box_corners(size_1), box_corners(size_2)

    def one(A: np.ndarray) -> float:
        b1 = (c1 @ A[:3, :3].T + A[:3, 3]).T  # (3, 8) as in the reference
        b2 = (c2 @ T2[:3, :3].T + T2[:3, 3]).T
        max1, min1 = b1.max(axis=0), b1.min(axis=0)
        max2, min2 = b2.max(axis=0), b2.min(axis=0)
        omin, omax = np.maximum(min1, min2), np.minimum(max1, max2)
        inter = 0.0 if np.min(omax - omin) < 0 else float(np.prod(omax - omin))
        union = float(np.prod(max1 - min1) + np.prod(max2 - min2) - inter)
        with np.errstate(divide="ignore", invalid="ignore"):
            return float(np.float64(inter) / np.float64(union))

    if not symmetric:
        return one(T1)
    vals = [one(T1 @ Rs) for Rs in _sym_rotations(sym_axis, sym_steps)]
    return float(np.nanmax(vals)) if not np.all(np.isnan(vals)) else float("nan")


def iou_accuracy(ious: Iterable[float], thresholds: Sequence[float] = IOU_THRESHOLDS) -> dict[str, float]:
    """Fraction of IoUs ``>= threshold`` for each threshold: ``{"iou25": ..., "iou50": ..., "iou75": ...}``.

    (The NOCS reference counts a detection as a true positive when its IoU is at least the threshold.)
    """
    v = np.asarray(list(ious), dtype=np.float64)
    if v.size == 0:
        raise ConfigError("ious must not be empty")
    return {f"iou{round(th * 100):d}": float(np.mean(v >= th)) for th in thresholds}


# --- shape --------------------------------------------------------------------------------------------

def chamfer_distance(a: np.ndarray, b: np.ndarray, squared: bool = False) -> float:
    """Symmetric Chamfer distance between point sets, in their unit (metres), with no extra scale factor.

    ``CD(a, b) = (mean_{x in a} min_{y in b} d(x, y) + mean_{y in b} min_{x in a} d(x, y)) / 2`` — the mean of
    the two directional means, with ``d`` the Euclidean distance, or its square when ``squared`` (then the
    unit is square metres). Papers differ: some report the sum of the two terms (2x this value) and scale
    it by 10^2 or 10^3; convert before comparing.

    Args:
        a: Points (N, 3), metres.
        b: Points (M, 3), metres.
        squared: Use squared distances.

    Returns:
        The Chamfer distance (metres, or square metres when ``squared``).
    """
    a = np.asarray(a, dtype=np.float64)
    b = np.asarray(b, dtype=np.float64)
    if a.ndim != 2 or b.ndim != 2 or a.shape[1] != b.shape[1] or len(a) == 0 or len(b) == 0:
        raise ConfigError(f"point sets must be non-empty (N, D) and (M, D) arrays, got {a.shape} and {b.shape}")
    dab, _ = cKDTree(b).query(a, k=1)
    dba, _ = cKDTree(a).query(b, k=1)
    if squared:
        dab, dba = dab**2, dba**2
    return float(0.5 * (dab.mean() + dba.mean()))
