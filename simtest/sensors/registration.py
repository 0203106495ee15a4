"""Depth-to-colour registration: a depth image of one camera seen by another (the RealSense driver's alignment),
by splatting each source pixel's footprint, or by the exact ray lookup for cameras that share a centre."""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from simtest.camera import pinhole_pixels, pinhole_points
from simtest.geometry import Pose

__all__ = ["register_depth"]


def _transform(T: Pose, p: np.ndarray) -> np.ndarray:
    """``T.apply`` for many points, column by column (numpy's matmul with a 3-wide inner axis is slow)."""
    R, t = T.R, T.t
    x, y, z = p[..., 0], p[..., 1], p[..., 2]
    return np.stack([R[i, 0] * x + R[i, 1] * y + R[i, 2] * z + t[i] for i in range(3)], axis=-1)


def _rescale_depth(depth: np.ndarray, K_src: np.ndarray, K_dst: np.ndarray, width: int, height: int) -> np.ndarray:
    """Registration between cameras with one centre and orientation: no parallax, so each destination pixel
    takes the source pixel its ray passes through (nearest), the same depth."""
    import cv2

    if np.array_equal(K_src, K_dst) and depth.shape == (height, width):
        return np.asarray(depth, dtype=np.float32).copy()
    mu, mv = _ray_maps(tuple(np.asarray(K_src, np.float64).ravel().tolist()),
                       tuple(np.asarray(K_dst, np.float64).ravel().tolist()), int(width), int(height))
    return cv2.remap(np.asarray(depth, dtype=np.float32), mu, mv, cv2.INTER_NEAREST,
                     borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)


@lru_cache(maxsize=8)
def _ray_maps(K_src: tuple[float, ...], K_dst: tuple[float, ...], width: int,
              height: int) -> tuple[np.ndarray, np.ndarray]:
    """The source pixel of each destination pixel's ray (one centre and orientation): ``cv2.remap`` maps."""
    (fs, _, cxs, _, gs, cys, *_), (fd, _, cxd, _, gd, cyd, *_) = K_src, K_dst
    u = (np.arange(width, dtype=np.float64) - cxd) / fd * fs + cxs
    v = (np.arange(height, dtype=np.float64) - cyd) / gd * gs + cys
    mu, mv = np.meshgrid(u.astype(np.float32), v.astype(np.float32))
    mu.setflags(write=False)
    mv.setflags(write=False)
    return mu, mv


def register_depth(depth: np.ndarray, K_src: np.ndarray, T_dst_src: Pose, K_dst: np.ndarray, width: int,
                   height: int) -> np.ndarray:
    """Depth-to-colour alignment: a depth image (metres, 0 = none) of a source camera seen by a destination
    camera (``T_dst_src`` maps source-frame points into it; ``width`` x ``height`` pixels, ``K_dst``).

    Each source pixel's footprint (its corners at its depth) is splatted into the destination image and the
    nearest surface kept (z-buffer); destination pixels no source pixel covers stay 0. Cameras with one centre
    and orientation (no parallax) take the exact shortcut: each destination ray's source pixel.
    """
    if np.allclose(T_dst_src.t, 0.0, atol=1e-9) and np.allclose(T_dst_src.R, np.eye(3), atol=1e-9):
        return _rescale_depth(depth, K_src, K_dst, width, height)
    d = np.asarray(depth, dtype=np.float64)
    v, u = np.nonzero(d > 0)
    z = d[v, u]
    out = np.full(height * width, np.inf)
    if z.size:
        corners = []
        for du, dv in ((-0.5, -0.5), (0.5, 0.5)):
            p = _transform(T_dst_src, pinhole_points(K_src, u + du, v + dv, z))
            zz = np.where(p[:, 2] > 1e-6, p[:, 2], np.nan)
            corners.append(pinhole_pixels(K_dst, p, zz))
        zc = _transform(T_dst_src, pinhole_points(K_src, u.astype(np.float64), v.astype(np.float64), z))[:, 2]
        (ua, va), (ub, vb) = corners
        good = np.isfinite(ua) & np.isfinite(ub) & np.isfinite(va) & np.isfinite(vb) & (zc > 0)
        lo_u = np.ceil(np.minimum(ua, ub)[good] - 1e-9).astype(np.int64)
        hi_u = np.floor(np.maximum(ua, ub)[good] - 1e-9).astype(np.int64)
        lo_v = np.ceil(np.minimum(va, vb)[good] - 1e-9).astype(np.int64)
        hi_v = np.floor(np.maximum(va, vb)[good] - 1e-9).astype(np.int64)
        # A footprint smaller than a pixel still lands on the pixel of its centre.
        hi_u, hi_v = np.maximum(hi_u, lo_u), np.maximum(hi_v, lo_v)
        zg = zc[good]
        span = int(min(8, max(1, (hi_u - lo_u).max(initial=0) + 1, (hi_v - lo_v).max(initial=0) + 1)))
        for oy in range(span):
            for ox in range(span):
                uu, vv = lo_u + ox, lo_v + oy
                ok = (uu <= hi_u) & (vv <= hi_v) & (uu >= 0) & (uu < width) & (vv >= 0) & (vv < height)
                np.minimum.at(out, vv[ok] * width + uu[ok], zg[ok])
    out[~np.isfinite(out)] = 0.0
    return out.reshape(height, width).astype(np.float32)
