"""Instance-level 6D pose errors, following the BOP toolkit (``bop_toolkit_lib/pose_error.py``).

Everything is in metres and radians unless a name says otherwise (``re`` returns degrees, as in BOP;
``mspd`` returns pixels). A pose ``(R, t)`` maps model points into the camera frame: ``x_c = R x_m + t``
(BOP ``cam_R_m2c``, ``cam_t_m2c`` converted to metres). Subscript ``e`` is the estimate, ``g`` the ground
truth. Symmetries are 4x4 transforms ``(S, 4, 4)`` in the model frame with the identity first, as returned by
:meth:`simtest.objects.ObjectModel.symmetry_transforms` (BOP ``misc.get_symmetry_transformations``).
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
from scipy.spatial import cKDTree

from simtest.errors import ConfigError
from simtest.render.zbuffer import depth_to_distance, render_depth

__all__ = [
    "add",
    "adi",
    "add_s",
    "re",
    "re_sym",
    "rotation_error_rad",
    "te",
    "mssd",
    "mspd",
    "vsd",
    "vsd_from_depth",
    "add_s_or_add",
    "add_01d",
    "as_symmetries",
    "MSPD_REFERENCE_WIDTH",
]

#: BOP normalises MSPD to a 640 px wide image: the error is scaled by ``640 / image_width``.
MSPD_REFERENCE_WIDTH = 640.0

#: Upper bound on the number of (symmetry, point) pairs processed at once by MSSD / MSPD.
_CHUNK = 1_000_000


def _rot(R: Any, name: str) -> np.ndarray:
    R = np.asarray(R, dtype=np.float64)
    if R.shape != (3, 3):
        R = R.reshape(-1)
        if R.shape != (9,):
            raise ConfigError(f"{name} must be a 3x3 rotation matrix, got shape {np.shape(R)}")
        R = R.reshape(3, 3)
    return R


def _vec(t: Any, name: str) -> np.ndarray:
    t = np.asarray(t, dtype=np.float64).reshape(-1)
    if t.shape != (3,):
        raise ConfigError(f"{name} must be a 3-vector (metres), got {t.size} values")
    return t


def _points(pts: Any) -> np.ndarray:
    pts = np.asarray(pts, dtype=np.float64)
    if pts.ndim != 2 or pts.shape[1] != 3 or len(pts) == 0:
        raise ConfigError(f"pts must be a non-empty (N, 3) array of model points (metres), got shape {pts.shape}")
    return pts


def as_symmetries(syms: Any) -> np.ndarray:
    """Normalise a symmetry set to an array (S, 4, 4), translations in metres.

    Args:
        syms: ``None`` (identity only), an array (S, 4, 4), or a sequence of BOP-style dicts with ``"R"``
            (3x3) and ``"t"`` (3,) in metres.

    Returns:
        (S, 4, 4) float64 transforms, in the given order.
    """
    if syms is None:
        return np.eye(4)[None]
    if isinstance(syms, np.ndarray) or (isinstance(syms, Sequence) and len(syms) and not isinstance(syms[0], dict)):
        arr = np.asarray(syms, dtype=np.float64)
        if arr.ndim == 2:
            arr = arr[None]
        if arr.ndim != 3 or arr.shape[1:] != (4, 4) or len(arr) == 0:
            raise ConfigError(f"symmetries must have shape (S, 4, 4) with S >= 1, got {arr.shape}")
        return arr
    if isinstance(syms, Sequence) and len(syms):
        out = np.tile(np.eye(4), (len(syms), 1, 1))
        for i, s in enumerate(syms):
            out[i, :3, :3] = _rot(s["R"], f"symmetry {i} R")
            out[i, :3, 3] = _vec(s["t"], f"symmetry {i} t")
        return out
    raise ConfigError(f"symmetries must be None, an (S, 4, 4) array or a list of {{'R', 't'}} dicts, got {syms!r}")


def _posed(pts: np.ndarray, R: np.ndarray, t: np.ndarray) -> np.ndarray:
    """``R x + t`` for every row ``x`` of ``pts`` (N, 3); metres in, metres out."""
    return np.asarray(pts, dtype=np.float64) @ np.asarray(R, dtype=np.float64).T + np.asarray(t, dtype=np.float64)


def add(R_e: np.ndarray, t_e: np.ndarray, R_g: np.ndarray, t_g: np.ndarray, pts: np.ndarray) -> float:
    """Average Distance of Model Points (ADD; Hinterstoisser et al. 2012; BOP ``add``).

    ``mean_i || (R_e x_i + t_e) - (R_g x_i + t_g) ||``.

    Args:
        R_e: Estimated rotation, 3x3 (model -> camera).
        t_e: Estimated translation (3,), metres.
        R_g: Ground-truth rotation, 3x3.
        t_g: Ground-truth translation (3,), metres.
        pts: Model points (N, 3), metres (usually the mesh vertices).

    Returns:
        ADD in metres.
    """
    pts = _points(pts)
    pe = _posed(pts, _rot(R_e, "R_e"), _vec(t_e, "t_e"))
    pg = _posed(pts, _rot(R_g, "R_g"), _vec(t_g, "t_g"))
    return float(np.linalg.norm(pe - pg, axis=1).mean())


def adi(R_e: np.ndarray, t_e: np.ndarray, R_g: np.ndarray, t_g: np.ndarray, pts: np.ndarray) -> float:
    """Average Distance of model points for objects with Indistinguishable views (ADD-S; BOP ``adi``).

    For each ground-truth-posed point, the distance to the nearest estimate-posed point; the mean of these.
    As in BOP, a KD-tree (``scipy.spatial.cKDTree``) is built over the estimate's points and queried with the
    ground truth's points. Always ``adi <= add``.

    Args:
        R_e: Estimated rotation, 3x3.
        t_e: Estimated translation (3,), metres.
        R_g: Ground-truth rotation, 3x3.
        t_g: Ground-truth translation (3,), metres.
        pts: Model points (N, 3), metres.

    Returns:
        ADD-S in metres.
    """
    pts = _points(pts)
    pe = _posed(pts, _rot(R_e, "R_e"), _vec(t_e, "t_e"))
    pg = _posed(pts, _rot(R_g, "R_g"), _vec(t_g, "t_g"))
    dist, _ = cKDTree(pe).query(pg, k=1)
    return float(np.mean(dist))


#: ADD-S under its common name; identical to :func:`adi`.
add_s = adi


def rotation_error_rad(R_e: np.ndarray, R_g: np.ndarray) -> float:
    """Geodesic angle between two rotations, radians in [0, pi].

    ``arccos(clip((trace(R_e R_g^T) - 1) / 2, -1, 1))``.
    """
    R_e, R_g = _rot(R_e, "R_e"), _rot(R_g, "R_g")
    cos = 0.5 * (np.trace(R_e @ R_g.T) - 1.0)
    return float(np.arccos(np.clip(cos, -1.0, 1.0)))


def re(R_e: np.ndarray, R_g: np.ndarray) -> float:
    """Rotation error in degrees (BOP ``re``): the geodesic angle of ``R_e R_g^T``, in [0, 180]."""
    return float(np.degrees(rotation_error_rad(R_e, R_g)))


def re_sym(R_e: np.ndarray, R_g: np.ndarray, syms: Any) -> float:
    """Smallest geodesic rotation error (degrees) between ``R_e`` and ``R_g R_s`` over the symmetry set.

    Args:
        R_e, R_g: 3x3 rotations (estimate, ground truth).
        syms: Symmetry transforms (S, 4, 4) or rotations (S, 3, 3), identity included (as returned by
            :meth:`simtest.objects.ObjectModel.symmetry_transforms`); equals :func:`re` for the identity alone.
    """
    S = np.asarray(syms, dtype=np.float64)
    if S.ndim != 3 or S.shape[1:] not in ((3, 3), (4, 4)) or len(S) == 0:
        raise ConfigError(f"syms must be (S, 4, 4) or (S, 3, 3) with S >= 1, got shape {S.shape}")
    M = _rot(R_g, "R_g").T @ _rot(R_e, "R_e")  # trace(R_e (R_g R_s)^T) = sum(M * R_s)
    tr = np.einsum("ij,sij->s", M, S[:, :3, :3])
    return float(np.degrees(np.arccos(np.clip(0.5 * (tr.max() - 1.0), -1.0, 1.0))))


def te(t_e: np.ndarray, t_g: np.ndarray) -> float:
    """Translation error ``|| t_g - t_e ||`` in metres (BOP ``te``, which works in millimetres)."""
    return float(np.linalg.norm(_vec(t_g, "t_g") - _vec(t_e, "t_e")))


def _sym_chunks(n_syms: int, n_pts: int):
    step = max(1, _CHUNK // max(n_pts, 1))
    for s in range(0, n_syms, step):
        yield slice(s, min(n_syms, s + step))


def mssd(R_e: np.ndarray, t_e: np.ndarray, R_g: np.ndarray, t_g: np.ndarray, pts: np.ndarray,
         syms: Any = None) -> float:
    """Maximum Symmetry-Aware Surface Distance (BOP ``mssd``; Hodan et al. 2020).

    ``min_S max_i || (R_e x_i + t_e) - (R_g (R_s x_i + t_s) + t_g) ||`` over the symmetry set ``S``.

    Args:
        R_e: Estimated rotation, 3x3.
        t_e: Estimated translation (3,), metres.
        R_g: Ground-truth rotation, 3x3.
        t_g: Ground-truth translation (3,), metres.
        pts: Model points (N, 3), metres (BOP uses the mesh vertices).
        syms: Symmetry transforms (S, 4, 4), identity first, translations in metres (or ``None`` for the
            identity only, or BOP-style ``[{"R", "t"}]`` dicts); see :func:`as_symmetries`.

    Returns:
        MSSD in metres.
    """
    pts = _points(pts)
    R_e, t_e, R_g, t_g = _rot(R_e, "R_e"), _vec(t_e, "t_e"), _rot(R_g, "R_g"), _vec(t_g, "t_g")
    S = as_symmetries(syms)
    if len(S) == 1:
        return _mssd_exact(R_e, t_e, R_g, t_g, pts, S)
    # The norm is rotation invariant: || R_e x + t_e - R_g (R_s x + t_s) - t_g || = || q - R_s x - t_s ||
    # with q = R_g^T (R_e x + t_e - t_g). Expanding the square turns the (S, N) distances into matrix
    # products: |q|^2 + |x|^2 + |t_s|^2 - 2 <R_s, q x^T> - 2 q.t_s + 2 (R_s^T t_s).x.
    q = _posed(pts, R_e, t_e) - t_g
    q = q @ R_g  # rows R_g^T (...)
    Rs, ts = S[:, :3, :3], S[:, :3, 3]
    base = (q * q).sum(axis=1) + (pts * pts).sum(axis=1)  # (N,)
    qx = (q[:, :, None] * pts[:, None, :]).reshape(len(pts), 9)  # (N, 9): q_i x_j
    # One matrix product: per symmetry [R_s (9), t_s (3), R_s^T t_s (3), |t_s|^2], per point
    # [-2 q x^T (9), -2 q (3), 2 x (3), 1].
    F = np.concatenate([Rs.reshape(len(S), 9), ts, np.einsum("sji,sj->si", Rs, ts),
                        (ts * ts).sum(axis=1, keepdims=True)], axis=1)
    G = np.concatenate([-2.0 * qx, -2.0 * q, 2.0 * pts, np.ones((len(pts), 1))], axis=1)
    d2max = np.empty(len(S))
    for sl in _sym_chunks(len(S), len(pts)):
        d2max[sl] = (F[sl] @ G.T + base[None, :]).max(axis=1)
    approx = np.sqrt(np.maximum(d2max, 0.0))  # (S,)
    # The expansion loses ~1e-9 m to cancellation; rescore the near-best symmetries exactly.
    cand = np.flatnonzero(approx <= approx.min() + 1e-6)
    return _mssd_exact(R_e, t_e, R_g, t_g, pts, S[cand])


def _mssd_exact(R_e: np.ndarray, t_e: np.ndarray, R_g: np.ndarray, t_g: np.ndarray, pts: np.ndarray,
                S: np.ndarray) -> float:
    pe = _posed(pts, R_e, t_e)
    R_gs = R_g @ S[:, :3, :3]  # (S, 3, 3)
    t_gs = S[:, :3, 3] @ R_g.T + t_g  # (S, 3)
    best = np.inf
    for sl in _sym_chunks(len(S), len(pts)):
        pg = np.matmul(pts[None], R_gs[sl].transpose(0, 2, 1)) + t_gs[sl, None, :]
        err = np.sqrt(((pe[None] - pg) ** 2).sum(axis=2)).max(axis=1)
        best = min(best, float(err.min()))
    return best


def _project(p: np.ndarray, K: np.ndarray) -> np.ndarray:
    q = p @ K.T
    return q[..., :2] / q[..., 2:3]


def mspd(R_e: np.ndarray, t_e: np.ndarray, R_g: np.ndarray, t_g: np.ndarray, K: np.ndarray, pts: np.ndarray,
         syms: Any = None, image_width: int | None = None) -> float:
    """Maximum Symmetry-Aware Projection Distance (BOP ``mspd``; Hodan et al. 2020).

    ``min_S max_i || proj(R_e x_i + t_e) - proj(R_g (R_s x_i + t_s) + t_g) ||`` in pixels, with the pinhole
    projection by ``K``. BOP19 makes MSPD comparable across image sizes by evaluating it as if the image were
    640 px wide (its correctness thresholds are scaled by ``image_width / 640``; equivalently the error is
    scaled by ``640 / image_width``). Pass ``image_width`` to get that normalised error; leave it ``None`` for
    the raw pixel error.

    Args:
        R_e: Estimated rotation, 3x3.
        t_e: Estimated translation (3,), metres.
        R_g: Ground-truth rotation, 3x3.
        t_g: Ground-truth translation (3,), metres.
        K: 3x3 intrinsics (pixels).
        pts: Model points (N, 3), metres.
        syms: Symmetry transforms (S, 4, 4), identity first (see :func:`mssd`).
        image_width: Width of the test image in pixels, to scale the error by ``640 / image_width``.

    Returns:
        MSPD in pixels (of a 640 px wide image when ``image_width`` is given).
    """
    pts = _points(pts)
    R_e, t_e, R_g, t_g = _rot(R_e, "R_e"), _vec(t_e, "t_e"), _rot(R_g, "R_g"), _vec(t_g, "t_g")
    K = _rot(K, "K")
    S = as_symmetries(syms)
    scale = 1.0
    if image_width is not None:
        if not image_width > 0:
            raise ConfigError(f"image_width must be > 0 pixels, got {image_width!r}")
        scale = MSPD_REFERENCE_WIDTH / float(image_width)
    pe = _project(_posed(pts, R_e, t_e), K)
    # Homogeneous image points of the symmetric GT poses: K (R_g (R_s x + t_s) + t_g) = A_s x + b_s.
    A = K @ R_g @ S[:, :3, :3]  # (S, 3, 3)
    b = (S[:, :3, 3] @ R_g.T + t_g) @ K.T  # (S, 3)
    best = np.inf
    for sl in _sym_chunks(len(S), len(pts)):
        h = np.matmul(pts[None], A[sl].transpose(0, 2, 1)) + b[sl, None, :]  # (s, N, 3)
        du = h[..., 0] / h[..., 2] - pe[None, :, 0]
        dv = h[..., 1] / h[..., 2] - pe[None, :, 1]
        err = np.sqrt((du * du + dv * dv).max(axis=1))
        best = min(best, float(err.min()))
    return best * scale


def _visib_mask(dist_test: np.ndarray, dist_model: np.ndarray, delta: float) -> np.ndarray:
    """BOP ``visibility._estimate_visib_mask`` in ``bop19`` mode."""
    d_diff = dist_model - dist_test
    return ((d_diff <= delta) | (dist_test == 0)) & (dist_model > 0)


def vsd_from_depth(depth_est: np.ndarray, depth_gt: np.ndarray, depth_test: np.ndarray, K: np.ndarray,
                   delta: float, taus: Sequence[float], diameter: float | None = None,
                   normalized_by_diameter: bool = True, cost_type: str = "step") -> np.ndarray:
    """Visible Surface Discrepancy from already rendered depth images (BOP ``vsd`` after its renders).

    The depth images are converted to distance images (:func:`simtest.render.zbuffer.depth_to_distance`); the
    visibility masks follow BOP19: a model pixel is visible where ``d_model - d_test <= delta`` or the test
    depth is missing (0); the estimate's mask also includes pixels visible in the ground truth where the
    estimate is rendered. Then, for each ``tau``::

        e(tau) = (sum over the visible intersection of cost(|d_gt - d_est| (/ diameter), tau)
                  + |union| - |intersection|) / |union|,   and 1 when the union is empty,

    with ``cost = [dist >= tau]`` (``"step"``) or ``min(1, dist / tau)`` (``"tlinear"``).

    Args:
        depth_est: Depth render of the model at the estimated pose (H, W), metres, 0 = empty.
        depth_gt: Depth render of the model at the ground-truth pose (H, W), metres, 0 = empty.
        depth_test: Test (measured) depth image (H, W), metres, 0 = no measurement.
        K: 3x3 intrinsics (pixels).
        delta: Visibility tolerance, metres (BOP: 0.015).
        taus: Misalignment tolerances: fractions of the diameter if ``normalized_by_diameter``, else metres
            (BOP19: 0.05, 0.10, ..., 0.50 of the diameter).
        diameter: Object diameter, metres (needed when ``normalized_by_diameter``).
        normalized_by_diameter: Divide the distance differences by ``diameter``.
        cost_type: ``"step"`` (BOP19) or ``"tlinear"``.

    Returns:
        Errors (len(taus),) in [0, 1].
    """
    if cost_type not in ("step", "tlinear"):
        raise ConfigError(f"cost_type must be 'step' or 'tlinear', got {cost_type!r}")
    if normalized_by_diameter and not (diameter is not None and diameter > 0):
        raise ConfigError(f"diameter must be > 0 metres when normalized_by_diameter, got {diameter!r}")
    taus = np.atleast_1d(np.asarray(taus, dtype=np.float64))
    if taus.ndim != 1 or len(taus) == 0 or np.any(taus <= 0):
        raise ConfigError(f"taus must be a non-empty list of values > 0, got {taus.tolist()}")
    shapes = {np.shape(depth_est), np.shape(depth_gt), np.shape(depth_test)}
    if len(shapes) != 1:
        raise ConfigError(f"depth images must have equal shapes, got est {np.shape(depth_est)}, "
                          f"gt {np.shape(depth_gt)}, test {np.shape(depth_test)}")
    dist_test = depth_to_distance(depth_test, K)
    dist_gt = depth_to_distance(depth_gt, K)
    dist_est = depth_to_distance(depth_est, K)
    visib_gt = _visib_mask(dist_test, dist_gt, delta)
    visib_est = _visib_mask(dist_test, dist_est, delta) | (visib_gt & (dist_est > 0))
    inter = visib_gt & visib_est
    union_count = int(np.count_nonzero(visib_gt | visib_est))
    if union_count == 0:
        return np.ones(len(taus))
    comp_count = union_count - int(np.count_nonzero(inter))
    dists = np.abs(dist_gt[inter] - dist_est[inter])
    if normalized_by_diameter:
        dists = dists / diameter
    if cost_type == "step":
        costs = (dists[None, :] >= taus[:, None]).sum(axis=1)
    else:
        costs = np.minimum(1.0, dists[None, :] / taus[:, None]).sum(axis=1)
    return (costs + comp_count) / float(union_count)


def _mesh_arrays(model: Any) -> tuple[np.ndarray, np.ndarray]:
    if hasattr(model, "vertices") and hasattr(model, "faces"):
        return np.asarray(model.vertices, dtype=np.float64), np.asarray(model.faces)
    try:
        vertices, faces = model
    except (TypeError, ValueError):
        raise ConfigError(f"model must be (vertices, faces) or have .vertices and .faces, got {type(model).__name__}"
                          ) from None
    return np.asarray(vertices, dtype=np.float64), np.asarray(faces)


def vsd(R_e: np.ndarray, t_e: np.ndarray, R_g: np.ndarray, t_g: np.ndarray, depth_test: np.ndarray,
        K: np.ndarray, model: Any, delta: float, taus: Sequence[float], diameter: float | None,
        normalized_by_diameter: bool = True, cost_type: str = "step") -> np.ndarray:
    """Visible Surface Discrepancy (BOP ``vsd``; Hodan et al. 2016, BOP19 variant).

    Renders the model's depth at both poses with :func:`simtest.render.zbuffer.render_depth` at the size of
    ``depth_test``, then applies :func:`vsd_from_depth`.

    Args:
        R_e: Estimated rotation, 3x3.
        t_e: Estimated translation (3,), metres.
        R_g: Ground-truth rotation, 3x3.
        t_g: Ground-truth translation (3,), metres.
        depth_test: Test depth image (H, W), metres (planar z), 0 = no measurement.
        K: 3x3 intrinsics of the test image (pixels).
        model: ``(vertices (N, 3) metres, faces (M, 3))`` or an object with ``.vertices`` and ``.faces``
            (e.g. :class:`simtest.objects.ObjectModel`).
        delta: Visibility tolerance, metres (BOP: 0.015).
        taus: Misalignment tolerances (fractions of ``diameter`` when normalised, else metres).
        diameter: Object diameter, metres.
        normalized_by_diameter: Divide distance differences by ``diameter`` (BOP19: True).
        cost_type: ``"step"`` (BOP19) or ``"tlinear"``.

    Returns:
        Errors (len(taus),) in [0, 1]; 0 for a perfect estimate, 1 when the renders do not overlap.
    """
    depth_test = np.asarray(depth_test)
    if depth_test.ndim != 2:
        raise ConfigError(f"depth_test must be a 2D image, got shape {depth_test.shape}")
    h, w = depth_test.shape
    vertices, faces = _mesh_arrays(model)
    depth_est = render_depth(vertices, faces, _rot(R_e, "R_e"), _vec(t_e, "t_e"), K, w, h)
    depth_gt = render_depth(vertices, faces, _rot(R_g, "R_g"), _vec(t_g, "t_g"), K, w, h)
    return vsd_from_depth(depth_est, depth_gt, depth_test, K, delta, taus, diameter,
                          normalized_by_diameter, cost_type)


def add_s_or_add(obj: Any, R_e: np.ndarray, t_e: np.ndarray, R_g: np.ndarray, t_g: np.ndarray,
                 pts: np.ndarray | None = None) -> float:
    """ADD-S (:func:`adi`) for a symmetric object, ADD (:func:`add`) otherwise; metres.

    Args:
        obj: An object with ``is_symmetric`` and ``vertices`` (e.g. :class:`simtest.objects.ObjectModel`).
        R_e: Estimated rotation, 3x3.
        t_e: Estimated translation (3,), metres.
        R_g: Ground-truth rotation, 3x3.
        t_g: Ground-truth translation (3,), metres.
        pts: Model points (N, 3), metres; defaults to ``obj.vertices``.

    Returns:
        ADD(-S) in metres.
    """
    pts = obj.vertices if pts is None else pts
    fn = adi if bool(obj.is_symmetric) else add
    return fn(R_e, t_e, R_g, t_g, pts)


def add_01d(obj: Any, R_e: np.ndarray, t_e: np.ndarray, R_g: np.ndarray, t_g: np.ndarray,
            pts: np.ndarray | None = None, fraction: float = 0.1) -> bool:
    """LINEMOD correctness: ADD(-S) ``< fraction x diameter`` (ADD-S for symmetric objects).

    Args:
        obj: An object with ``is_symmetric``, ``vertices`` and ``diameter`` (metres).
        R_e: Estimated rotation, 3x3.
        t_e: Estimated translation (3,), metres.
        R_g: Ground-truth rotation, 3x3.
        t_g: Ground-truth translation (3,), metres.
        pts: Model points (N, 3), metres; defaults to ``obj.vertices``.
        fraction: Threshold as a fraction of the diameter (0.1 in the ADD(-S)-0.1d protocol).

    Returns:
        Whether the estimate is correct.
    """
    if not fraction > 0:
        raise ConfigError(f"fraction must be > 0, got {fraction!r}")
    return bool(add_s_or_add(obj, R_e, t_e, R_g, t_g, pts) < fraction * float(obj.diameter))
