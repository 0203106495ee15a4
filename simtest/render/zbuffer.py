"""A vectorised numpy z-buffer rasterizer for depth images (no OpenGL).

Used where an exact, dependency-free depth render of one mesh is needed, e.g. the VSD pose error
(:func:`simtest.metrics.pose.vsd`), which follows the BOP toolkit's renderer-based definition.

Conventions (the same as :mod:`simtest.camera`):

* Camera frame OpenCV: x right, y down, z forward; vertices in metres.
* Pixel centres at integer coordinates: pixel ``(row v, col u)`` is sampled at the image point ``(u, v)``.
  A pixel belongs to a triangle when its centre lies inside the projected triangle or on its boundary
  (pixels on an edge shared by two triangles are written by both; the z-buffer keeps the nearer one).
* Depth is planar z (metres), ``0`` where no triangle covers the pixel centre.
* The depth at a pixel centre is exact for the triangle's plane: ``1 / z`` is affine in image coordinates
  for a planar triangle, so it is interpolated with screen-space barycentrics and inverted
  (perspective-correct interpolation).
* No near-plane clipping: a triangle with any vertex at ``z <= znear`` is skipped. No back-face culling.
"""

from __future__ import annotations

import numpy as np

from simtest.errors import ConfigError

__all__ = ["rasterize_depth", "render_depth", "depth_to_distance"]

#: Tolerance (in barycentric units) of the inside test, so that pixel centres on an edge are kept.
_INSIDE_EPS = 1e-9


def _check_K(K: np.ndarray) -> np.ndarray:
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3):
        raise ConfigError(f"intrinsics K must be 3x3, got shape {K.shape}")
    if not (K[0, 0] > 0 and K[1, 1] > 0):
        raise ConfigError(f"focal lengths must be > 0 pixels, got fx={K[0, 0]!r}, fy={K[1, 1]!r}")
    return K


def rasterize_depth(vertices_cam: np.ndarray, faces: np.ndarray, K: np.ndarray, width: int, height: int,
                    znear: float = 1e-4, max_pairs: int = 2_000_000) -> np.ndarray:
    """Render the planar depth image of a triangle mesh given in the camera frame.

    Every triangle's candidate pixels (the integer pixel centres inside its projected bounding box) are
    enumerated in vectorised batches; pixels whose centre lies inside the triangle get the exact planar
    depth of the triangle at that centre, and the z-buffer keeps the minimum per pixel.

    Args:
        vertices_cam: Vertices (N, 3) in the OpenCV camera frame, metres.
        faces: Triangles (M, 3), integer indices into ``vertices_cam``.
        K: 3x3 intrinsics (pixels), OpenCV convention (pixel centres at integer coordinates).
        width: Image width (pixels).
        height: Image height (pixels).
        znear: Triangles with any vertex at ``z <= znear`` (metres) are skipped (no clipping).
        max_pairs: Upper bound on (triangle, pixel) candidates processed at once (memory ~ 100 B each);
            a single triangle larger than this is processed alone.

    Returns:
        Depth image (height, width), float32, planar z in metres; 0 where the mesh does not cover the
        pixel centre.

    Raises:
        ConfigError: On malformed inputs (the message names the bad value).
    """
    V, F, K, width, height = _check_mesh_inputs(vertices_cam, faces, K, width, height, max_pairs)
    tris = _project_triangles(V, F, K, width, height, znear)
    if tris is None:
        return np.zeros((height, width), dtype=np.float32)
    spans = _row_spans(tris, width)
    zbuf = np.full(height * width, np.inf)
    _fill_spans(zbuf, width, spans, max_pairs)
    zbuf[~np.isfinite(zbuf)] = 0.0
    return zbuf.reshape(height, width).astype(np.float32)


def _check_mesh_inputs(vertices_cam, faces, K, width, height, max_pairs):
    """Validated ``(V float64 (N, 3), F int (M, 3), K, width, height)``.

    Raises:
        ConfigError: On malformed inputs (the message names the bad value).
    """
    V = np.asarray(vertices_cam, dtype=np.float64)
    F = np.asarray(faces)
    if V.ndim != 2 or V.shape[1] != 3:
        raise ConfigError(f"vertices_cam must have shape (N, 3), got {V.shape}")
    if F.ndim != 2 or F.shape[1] != 3 or not np.issubdtype(F.dtype, np.integer):
        raise ConfigError(f"faces must be an integer array of shape (M, 3), got {F.shape} {F.dtype}")
    if len(F) and (F.min() < 0 or F.max() >= len(V)):
        raise ConfigError(f"faces index vertices in [{F.min()}, {F.max()}] but there are {len(V)} vertices")
    K = _check_K(K)
    width, height = int(width), int(height)
    if width < 1 or height < 1:
        raise ConfigError(f"image size must be >= 1 pixel, got {width!r}x{height!r}")
    if max_pairs < 1:
        raise ConfigError(f"max_pairs must be >= 1, got {max_pairs!r}")
    return V, F, K, width, height


def _project_triangles(V: np.ndarray, F: np.ndarray, K: np.ndarray, width: int, height: int, znear: float):
    """Project the triangles in front of the camera; ``None`` when none covers a pixel centre.

    Returns:
        ``(u (T, 3), v (T, 3), umin, vmin, vmax (T,) int pixel bounds, (ai, ci, di) (T,) each)`` with
        ``1/z = ai (u - umin) + ci (v - vmin) + di`` over each kept triangle.
    """
    if len(F) == 0:
        return None
    # Drop triangles behind (or too close to) the camera, then project.
    tri = V[F]  # (M, 3 vertices, 3 coords)
    tri = tri[np.all(tri[:, :, 2] > znear, axis=1)]
    if len(tri) == 0:
        return None
    proj = tri @ K.T
    iz = 1.0 / tri[:, :, 2]  # (M, 3): 1 / z of each vertex
    u = proj[:, :, 0] * iz
    v = proj[:, :, 1] * iz

    # Signed doubled area; degenerate (zero-area) projections cover no pixel centre in a stable way.
    u0, u1, u2 = u[:, 0], u[:, 1], u[:, 2]
    v0, v1, v2 = v[:, 0], v[:, 1], v[:, 2]
    area2 = (u1 - u0) * (v2 - v0) - (u2 - u0) * (v1 - v0)
    umin = np.maximum(np.ceil(u.min(axis=1) - 1e-9), 0)
    umax = np.minimum(np.floor(u.max(axis=1) + 1e-9), width - 1)
    vmin = np.maximum(np.ceil(v.min(axis=1) - 1e-9), 0)
    vmax = np.minimum(np.floor(v.max(axis=1) + 1e-9), height - 1)
    keep = (np.abs(area2) > 1e-12) & (umax >= umin) & (vmax >= vmin)
    if not np.any(keep):
        return None
    u0, u1, u2, v0, v1, v2 = u0[keep], u1[keep], u2[keep], v0[keep], v1[keep], v2[keep]
    area2, iz = area2[keep], iz[keep]
    umin = umin[keep].astype(np.int64)
    vmin, vmax = vmin[keep].astype(np.int64), vmax[keep].astype(np.int64)

    # 1/z is affine in (u, v) over a planar triangle: 1/z = a u + c v + d. Coefficients per triangle,
    # with (u, v) measured from the bounding-box corner (umin, vmin) to keep them well conditioned.
    inv = 1.0 / area2
    du0, du1, du2 = u0 - umin, u1 - umin, u2 - umin
    dv0, dv1, dv2 = v0 - vmin, v1 - vmin, v2 - vmin
    iz0, iz1, iz2 = iz[:, 0], iz[:, 1], iz[:, 2]
    # Barycentric b0 = a0 u + c0 v + d0 (and b1 likewise); 1/z = b0 iz0 + b1 iz1 + (1 - b0 - b1) iz2.
    a0, c0, d0 = (dv1 - dv2) * inv, (du2 - du1) * inv, (du1 * dv2 - du2 * dv1) * inv
    a1, c1, d1 = (dv2 - dv0) * inv, (du0 - du2) * inv, (du2 * dv0 - du0 * dv2) * inv
    ai = a0 * (iz0 - iz2) + a1 * (iz1 - iz2)
    ci = c0 * (iz0 - iz2) + c1 * (iz1 - iz2)
    di = d0 * (iz0 - iz2) + d1 * (iz1 - iz2) + iz2
    u = np.stack([u0, u1, u2], axis=1)
    v = np.stack([v0, v1, v2], axis=1)
    return u, v, umin, vmin, vmax, (ai, ci, di)


def _row_spans(tris, width: int):
    """Scanlines: one (triangle, row) pair per pixel row crossed by the triangle's bounding box; the covered
    pixel centres of that row form the span between the row's crossings of the edges.

    Returns:
        ``(rows, first column, span length, first column relative to the bounding box, 1/z at relative column
        0, 1/z slope per column)`` of the non-empty spans.
    """
    u, v, umin, vmin, vmax, (ai, ci, di) = tris
    nrows = vmax - vmin + 1
    tri_of_row = np.repeat(np.arange(len(nrows)), nrows)
    row_first = np.cumsum(nrows) - nrows
    rows = vmin[tri_of_row] + (np.arange(int(nrows.sum()), dtype=np.int64) - row_first[tri_of_row])
    y = rows.astype(np.float64)
    eu = u[tri_of_row]  # (P, 3)
    ev = v[tri_of_row]
    ul = np.full(len(rows), np.inf)
    ur = np.full(len(rows), -np.inf)
    for i, j in ((0, 1), (1, 2), (2, 0)):
        ua, ub, va, vb = eu[:, i], eu[:, j], ev[:, i], ev[:, j]
        lo, hi = np.minimum(va, vb), np.maximum(va, vb)
        hit = (y >= lo - 1e-9) & (y <= hi + 1e-9)
        dv = vb - va
        flat = np.abs(dv) < 1e-12
        with np.errstate(divide="ignore", invalid="ignore"):
            ux = np.where(flat, ua, ua + (np.clip(y, lo, hi) - va) * (ub - ua) / np.where(flat, 1.0, dv))
        ux2 = np.where(flat, ub, ux)
        ul = np.where(hit, np.minimum(ul, np.minimum(ux, ux2)), ul)
        ur = np.where(hit, np.maximum(ur, np.maximum(ux, ux2)), ur)
    ok = ur >= ul
    pl = np.maximum(np.ceil(np.where(ok, ul, 0.0) - 1e-9), 0).astype(np.int64)
    pr = np.minimum(np.floor(np.where(ok, ur, -1.0) + 1e-9), width - 1).astype(np.int64)
    span = np.where(ok, np.maximum(pr - pl + 1, 0), 0)
    sel = span > 0
    tri_of_row, rows, pl, span = tri_of_row[sel], rows[sel], pl[sel], span[sel]
    coef = np.stack([ai, ci, di], axis=1)[tri_of_row]
    # Row and column offsets from the triangle's bounding-box corner, as used by the coefficients.
    rrel = (rows - vmin[tri_of_row]).astype(np.float64)
    crel0 = pl - umin[tri_of_row]
    iz_row = coef[:, 1] * rrel + coef[:, 2]  # 1/z at column offset 0 of each row
    return rows, pl, span, crel0, iz_row, coef[:, 0]


def _fill_spans(zbuf: np.ndarray, width: int, spans, max_pairs: int) -> None:
    """Keep the minimum depth of every span pixel in the flat z-buffer, ``max_pairs`` pixels per batch."""
    rows, pl, span, crel0, iz_row, slope = spans
    ends = np.cumsum(span)
    n = len(span)
    start = 0
    while start < n:
        base = ends[start - 1] if start else 0
        stop = max(int(np.searchsorted(ends, base + max_pairs, side="right")), start + 1)
        sl = slice(start, stop)
        cnt = span[sl]
        total = int(cnt.sum())
        k = np.arange(total, dtype=np.int64) - np.repeat(np.cumsum(cnt) - cnt, cnt)
        crel = np.repeat(crel0[sl], cnt) + k
        izp = np.repeat(slope[sl], cnt) * crel + np.repeat(iz_row[sl], cnt)
        pix = np.repeat(rows[sl] * width + pl[sl], cnt) + k
        good = izp > 0
        np.minimum.at(zbuf, pix[good], 1.0 / izp[good])
        start = stop


def render_depth(vertices: np.ndarray, faces: np.ndarray, R: np.ndarray, t: np.ndarray, K: np.ndarray,
                 width: int, height: int) -> np.ndarray:
    """Depth image of a model placed at pose ``(R, t)`` in the camera frame.

    Args:
        vertices: Model vertices (N, 3), metres.
        faces: Triangles (M, 3).
        R: 3x3 rotation, model -> camera (BOP ``cam_R_m2c``).
        t: Translation (3,), metres, model -> camera.
        K: 3x3 intrinsics (pixels).
        width: Image width (pixels).
        height: Image height (pixels).

    Returns:
        Planar depth (height, width), float32, metres, 0 where empty; see :func:`rasterize_depth`.
    """
    R = np.asarray(R, dtype=np.float64).reshape(3, 3)
    t = np.asarray(t, dtype=np.float64).reshape(3)
    vc = np.asarray(vertices, dtype=np.float64) @ R.T + t
    return rasterize_depth(vc, faces, K, width, height)


def depth_to_distance(depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Convert planar depth to the distance from the camera centre along each pixel's ray.

    ``dist(u, v) = depth(u, v) * sqrt(((u - cx) / fx)^2 + ((v - cy) / fy)^2 + 1)``, pixel centres at
    integer coordinates (BOP toolkit ``misc.depth_im_to_dist_im_fast``). Zero depth stays zero.

    Args:
        depth: Planar depth image (H, W), metres (any unit works; the output has the same unit).
        K: 3x3 intrinsics (pixels).

    Returns:
        Distance image (H, W), float64, same unit as ``depth``.
    """
    depth = np.asarray(depth)
    if depth.ndim != 2:
        raise ConfigError(f"depth must be a 2D image, got shape {depth.shape}")
    K = _check_K(K)
    h, w = depth.shape
    x = (np.arange(w, dtype=np.float64) - K[0, 2]) / K[0, 0]
    y = (np.arange(h, dtype=np.float64) - K[1, 2]) / K[1, 1]
    scale = np.sqrt(x[None, :] ** 2 + y[:, None] ** 2 + 1.0)
    return depth.astype(np.float64) * scale
