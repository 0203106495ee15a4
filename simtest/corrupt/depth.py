"""Depth-sensor noise models on planar depth images in metres.

Depth is ``float32 (H, W)`` planar z in metres; ``0`` means "no measurement" and stays ``0`` through every
function here (noise never creates a measurement where there was none, and a value pushed to ``<= 0`` becomes
missing). Each model is built from small parts with one signature::

    part(depth, rng, *, K=None, rgb=None, **params) -> depth

``K`` is the 3x3 OpenCV intrinsics matrix (pixels) of the depth image, ``rgb`` an optional registered
``(H, W, 3)`` uint8 image of the same scene (clean, i.e. before any image corruption) used by the
dark/specular dropout parts; parts that need ``rgb`` do nothing without it. Parts are composed into the named
presets of :data:`simtest.corrupt.depth_presets.DEPTH_PRESETS`, applied by
:func:`simtest.corrupt.depth_presets.apply_depth_noise`.

Models:
  * Kinect v1 (Nguyen, Izadi & Lovell 2012): axial ``sigma_z = 0.0012 + 0.0019 (z - 0.4)^2`` m, plus
    ``0.0001 theta^2 / (sqrt(z) (pi/2 - theta)^2)`` m for ``theta > 60 deg``; lateral
    ``sigma_L = 0.8 + 0.035 theta / (pi/2 - theta)`` px, with ``theta`` the angle between the surface normal
    (from depth and ``K``) and the viewing ray. ``theta`` is clipped to 85 deg in the formulas (both diverge
    at 90 deg; grazing pixels are dropped by :func:`grazing_dropout` anyway).
  * Structured light (Handa et al. 2014, ICL-NUIM): bilinear pixel shifts (sigma 0.5 px), disparity
    ``f b / z`` (f = 480 px, b = 0.075 m) quantised to 1/8 px, invalidation near depth edges (the 9x9 window
    test of the ICL-NUIM code, every pixel treated as a projected dot since no dot-pattern image is
    bundled), then ``z' = 35130 / round(35130 / round(z_cm) + N(0, 1) / 6 + 0.5)``.
  * Azure Kinect-like: pixel shifts (sigma 0.25 px), additive ``(0.0005 + max(z - 0.5, 0) 0.001) N(0, 1)`` m,
    zero where the 3x3 depth range exceeds 0.8 m and where the grey level is below 15.
  * Active stereo (RealSense D435-like): ``sigma_z = z^2 sigma_d / (f b)``, disparity quantisation, missing
    data at depth edges, on dark and specular surfaces, random holes, valid range 0.2-10 m.
"""

from __future__ import annotations

from typing import Callable

import cv2
import numpy as np

from simtest.errors import ConfigError

__all__ = [
    "check_rgb",
    "keep_missing",
    "require_K",
    "surface_normals",
    "incidence_angle",
    "kinect_axial_sigma",
    "kinect_lateral_sigma",
    "azure_sigma",
    "stereo_sigma",
    "pixel_shift",
    "kinect_lateral_noise",
    "kinect_axial_noise",
    "azure_axial_noise",
    "stereo_axial_noise",
    "disparity_quantization",
    "structured_light_edge_filter",
    "structured_light_noise",
    "discontinuity_dropout",
    "edge_dropout",
    "dark_dropout",
    "specular_dropout",
    "grazing_dropout",
    "random_holes",
    "quantize_depth",
    "range_limits",
]

DepthPart = Callable[..., np.ndarray]

#: Incidence angles are clipped to this value (radians, 85 deg) inside the Kinect formulas.
MAX_THETA = np.deg2rad(85.0)


# --------------------------------------------------------------------------------------------------------
# geometry
# --------------------------------------------------------------------------------------------------------
def require_K(K: np.ndarray | None, part: str) -> np.ndarray:
    """``K`` as a checked 3x3 float array; ``part`` names the caller in the error."""
    if K is None:
        raise ConfigError(f"depth noise part {part!r} needs the intrinsics K (3x3, pixels), got None")
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3):
        raise ConfigError(f"intrinsics K must be a 3x3 matrix, got shape {K.shape}")
    return K


def check_rgb(rgb: np.ndarray | None, depth: np.ndarray) -> np.ndarray | None:
    """``rgb`` checked to be an (H, W, 3) uint8 image of the depth's size, or ``None``."""
    if rgb is None:
        return None
    rgb = np.asarray(rgb)
    if rgb.shape != depth.shape + (3,) or rgb.dtype != np.uint8:
        raise ConfigError(f"rgb must be uint8 of shape {depth.shape + (3,)} to match the depth image, got "
                          f"{rgb.dtype} {rgb.shape}")
    return rgb


def keep_missing(out: np.ndarray, depth: np.ndarray) -> np.ndarray:
    """Zero where the input was missing, and where the output is non-finite or <= 0."""
    out = np.where((depth > 0) & np.isfinite(out) & (out > 0), out, 0.0)
    return out.astype(np.float32)


def surface_normals(depth: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-pixel unit surface normals (camera frame) from planar depth and intrinsics.

    Back-projects every pixel, takes central differences of the 3D points along image rows and columns and
    crosses them. Normals face the camera (negative z component).

    Args:
        depth: ``(H, W)`` planar depth, metres (0 = missing).
        K: 3x3 intrinsics, pixels.

    Returns:
        ``(normals, valid)``: ``(H, W, 3)`` float32 unit normals (0 where invalid) and an ``(H, W)`` bool mask,
        false where the pixel or one of its 4-neighbours has no depth.
    """
    K = require_K(K, "surface_normals")
    z = np.asarray(depth, dtype=np.float32)
    h, w = z.shape
    u = (np.arange(w, dtype=np.float32) - np.float32(K[0, 2])) / np.float32(K[0, 0])
    v = (np.arange(h, dtype=np.float32) - np.float32(K[1, 2])) / np.float32(K[1, 1])
    X, Y = u[None, :] * z, v[:, None] * z
    # central differences along columns (d/du) and rows (d/dv), one-sided at the image border
    grads = [np.gradient(c, axis=(1, 0)) if min(h, w) > 1 else (np.zeros_like(z), np.zeros_like(z))
             for c in (X, Y, z)]
    (xu, xv), (yu, yv), (zu, zv) = grads
    nx = yu * zv - zu * yv
    ny = zu * xv - xu * zv
    nz = xu * yv - yu * xv
    norm = np.sqrt(nx * nx + ny * ny + nz * nz)
    present = z > 0
    nb = present.copy()
    nb[1:] &= present[:-1]
    nb[:-1] &= present[1:]
    nb[:, 1:] &= present[:, :-1]
    nb[:, :-1] &= present[:, 1:]
    valid = nb & (norm > 0)
    inv = np.where(valid, 1.0 / np.where(valid, norm, 1.0), 0.0).astype(np.float32)
    inv = np.where(nz > 0, -inv, inv)  # face the camera
    n = np.stack([nx * inv, ny * inv, nz * inv], axis=-1)
    return n.astype(np.float32), valid


def incidence_angle(depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Angle (radians, 0..pi/2) between the surface normal and the viewing ray; 0 where undefined."""
    K = require_K(K, "incidence_angle")
    n, valid = surface_normals(depth, K)
    h, w = depth.shape
    u = (np.arange(w, dtype=np.float32) - np.float32(K[0, 2])) / np.float32(K[0, 0])
    v = (np.arange(h, dtype=np.float32) - np.float32(K[1, 2])) / np.float32(K[1, 1])
    inv_len = 1.0 / np.sqrt(u[None, :] ** 2 + v[:, None] ** 2 + 1.0)
    cos = np.abs(n[..., 0] * u[None, :] + n[..., 1] * v[:, None] + n[..., 2]) * inv_len
    theta = np.arccos(np.clip(cos, 0.0, 1.0))
    return np.where(valid, theta, 0.0).astype(np.float32)


# --------------------------------------------------------------------------------------------------------
# noise formulas (metres, pixels)
# --------------------------------------------------------------------------------------------------------
def kinect_axial_sigma(z: np.ndarray | float, theta: np.ndarray | float = 0.0) -> np.ndarray:
    """Kinect v1 axial noise std (metres) at depth ``z`` (m) and incidence ``theta`` (rad), Nguyen 2012."""
    z = np.asarray(z, dtype=np.float64)
    t = np.minimum(np.asarray(theta, dtype=np.float64), MAX_THETA)
    sigma = 0.0012 + 0.0019 * (z - 0.4) ** 2
    with np.errstate(divide="ignore", invalid="ignore"):
        extra = 0.0001 * t ** 2 / (np.sqrt(np.maximum(z, 1e-6)) * (np.pi / 2 - t) ** 2)
    return sigma + np.where(t > np.pi / 3, extra, 0.0)


def kinect_lateral_sigma(theta: np.ndarray | float) -> np.ndarray:
    """Kinect v1 lateral noise std (pixels) at incidence ``theta`` (rad), Nguyen 2012."""
    t = np.minimum(np.asarray(theta, dtype=np.float64), MAX_THETA)
    return 0.8 + 0.035 * t / (np.pi / 2 - t)


def azure_sigma(z: np.ndarray | float) -> np.ndarray:
    """Azure Kinect-like axial noise std (metres): ``0.0005 + max(z - 0.5, 0) * 0.001``."""
    return 0.0005 + np.maximum(np.asarray(z, dtype=np.float64) - 0.5, 0.0) * 0.001


def stereo_sigma(z: np.ndarray | float, focal_px: float, baseline_m: float, sigma_disparity_px: float) -> np.ndarray:
    """Active/passive stereo depth std (metres): ``z^2 sigma_d / (f b)``."""
    z = np.asarray(z, dtype=np.float64)
    return z ** 2 * sigma_disparity_px / (focal_px * baseline_m)


# --------------------------------------------------------------------------------------------------------
# parts: lateral
# --------------------------------------------------------------------------------------------------------
def _sample(depth: np.ndarray, map_x: np.ndarray, map_y: np.ndarray, bilinear: bool) -> np.ndarray:
    """Sample depth at float pixel coordinates (clamped to the image).

    Bilinear sampling falls back to nearest wherever one of the four taps is missing, so a hole never
    averages into a fake in-between depth.
    """
    h, w = depth.shape
    map_x = np.clip(map_x, 0, w - 1).astype(np.float32)
    map_y = np.clip(map_y, 0, h - 1).astype(np.float32)
    near = cv2.remap(depth, map_x, map_y, cv2.INTER_NEAREST)
    if not bilinear:
        return near
    lin = cv2.remap(depth, map_x, map_y, cv2.INTER_LINEAR)
    valid = cv2.remap((depth > 0).astype(np.float32), map_x, map_y, cv2.INTER_LINEAR)
    return np.where(valid > 0.999, lin, near)


def pixel_shift(depth: np.ndarray, rng: np.random.Generator, *, sigma_px: float = 0.5, bilinear: bool = True,
                K: np.ndarray | None = None, rgb: np.ndarray | None = None) -> np.ndarray:
    """Lateral noise: resample every pixel at an offset ``N(0, sigma_px)`` in x and y (pixels).

    Args:
        sigma_px: Std of the offsets (pixels); 0.5 in ICL-NUIM, 0.25 for the Azure-like model.
        bilinear: Bilinear interpolation (nearest next to holes) if true, else nearest neighbour.
    """
    depth = np.asarray(depth, dtype=np.float32)
    h, w = depth.shape
    d = rng.standard_normal((2, h, w), dtype=np.float32) * np.float32(sigma_px)
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    return keep_missing(_sample(depth, gx + d[0], gy + d[1], bilinear), depth)


def kinect_lateral_noise(depth: np.ndarray, rng: np.random.Generator, *, K: np.ndarray | None = None,
                         rgb: np.ndarray | None = None) -> np.ndarray:
    """Kinect v1 lateral noise: nearest-neighbour resampling at offsets ``N(0, sigma_L(theta))`` px."""
    K = require_K(K, "kinect_lateral_noise")
    depth = np.asarray(depth, dtype=np.float32)
    h, w = depth.shape
    sigma = kinect_lateral_sigma(incidence_angle(depth, K)).astype(np.float32)
    d = rng.standard_normal((2, h, w), dtype=np.float32) * sigma
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    return keep_missing(_sample(depth, gx + d[0], gy + d[1], bilinear=False), depth)


# --------------------------------------------------------------------------------------------------------
# parts: axial
# --------------------------------------------------------------------------------------------------------
def kinect_axial_noise(depth: np.ndarray, rng: np.random.Generator, *, K: np.ndarray | None = None,
                       rgb: np.ndarray | None = None) -> np.ndarray:
    """Kinect v1 axial noise: ``z + N(0, sigma_z(z, theta))`` with Nguyen's formula (metres)."""
    K = require_K(K, "kinect_axial_noise")
    depth = np.asarray(depth, dtype=np.float32)
    sigma = kinect_axial_sigma(depth, incidence_angle(depth, K)).astype(np.float32)
    noise = rng.standard_normal(depth.shape, dtype=np.float32) * sigma
    return keep_missing(depth + noise, depth)


def azure_axial_noise(depth: np.ndarray, rng: np.random.Generator, *, K: np.ndarray | None = None,
                      rgb: np.ndarray | None = None) -> np.ndarray:
    """Azure Kinect-like axial noise: ``z + (0.0005 + max(z - 0.5, 0) 0.001) N(0, 1)`` (metres)."""
    depth = np.asarray(depth, dtype=np.float32)
    noise = rng.standard_normal(depth.shape, dtype=np.float32) * azure_sigma(depth).astype(np.float32)
    return keep_missing(depth + noise, depth)


def stereo_axial_noise(depth: np.ndarray, rng: np.random.Generator, *, focal_px: float = 640.0,
                       baseline_m: float = 0.05, sigma_disparity_px: float = 0.08, K: np.ndarray | None = None,
                       rgb: np.ndarray | None = None) -> np.ndarray:
    """Stereo axial noise ``z + N(0, z^2 sigma_d / (f b))`` (metres; f, sigma_d in pixels, b in metres)."""
    depth = np.asarray(depth, dtype=np.float32)
    sigma = stereo_sigma(depth, focal_px, baseline_m, sigma_disparity_px).astype(np.float32)
    return keep_missing(depth + rng.standard_normal(depth.shape, dtype=np.float32) * sigma, depth)


def disparity_quantization(depth: np.ndarray, rng: np.random.Generator, *, focal_px: float = 480.0,
                           baseline_m: float = 0.075, step_px: float = 0.125, K: np.ndarray | None = None,
                           rgb: np.ndarray | None = None) -> np.ndarray:
    """Round the disparity ``f b / z`` to ``step_px`` pixels and convert back (deterministic)."""
    depth = np.asarray(depth, dtype=np.float32)
    fb = focal_px * baseline_m
    with np.errstate(divide="ignore", invalid="ignore"):
        disp = np.round(fb / depth.astype(np.float64) / step_px) * step_px
        out = fb / disp
    return keep_missing(out, depth)


def structured_light_edge_filter(depth: np.ndarray, rng: np.random.Generator, *, focal_px: float = 480.0,
                                 baseline_m: float = 0.075, window: int = 9, inlier_px: float = 0.1,
                                 K: np.ndarray | None = None, rgb: np.ndarray | None = None) -> np.ndarray:
    """Invalidate pixels near depth edges and holes with the ICL-NUIM 9x9 window test (deterministic).

    For each pixel, the disparities ``d`` in its ``window x window`` neighbourhood must all be valid, and more
    than ``1 / 1.2`` of them must satisfy ``|d(q) - mean| w(q) < inlier_px`` with ``w = 1 / (1.2^2 r^2)``
    (``r`` the distance to the centre in pixels, ``w = 1`` at the centre). Pixels within ``window // 2`` of
    the image border are invalid, as in the reference. Vectorised over the ``window^2`` offsets.
    """
    depth = np.asarray(depth, dtype=np.float32)
    h, w = depth.shape
    r = window // 2
    valid = depth > 0
    with np.errstate(divide="ignore"):
        disp = np.where(valid, np.float32(focal_px * baseline_m) / depth, 0.0).astype(np.float32)
    all_valid = cv2.erode(valid.astype(np.uint8), np.ones((window, window), np.uint8),
                          borderType=cv2.BORDER_CONSTANT, borderValue=0).astype(bool)
    mean = cv2.blur(disp, (window, window), borderType=cv2.BORDER_REPLICATE)
    pad = np.pad(disp, r, mode="edge")
    count = np.zeros((h, w), dtype=np.int16)
    for dy in range(-r, r + 1):
        for dx in range(-r, r + 1):
            sq = dy * dy + dx * dx
            weight = np.float32(1.0 if sq == 0 else 1.0 / (sq * 1.44))
            shifted = pad[r + dy:r + dy + h, r + dx:r + dx + w]
            count += np.abs(shifted - mean) * weight < inlier_px
    keep = all_valid & (count > window * window / 1.2)
    keep[:r] = keep[h - r:] = False
    keep[:, :r] = keep[:, w - r:] = False
    return np.where(keep, depth, 0.0).astype(np.float32)


def structured_light_noise(depth: np.ndarray, rng: np.random.Generator, *, K: np.ndarray | None = None,
                           rgb: np.ndarray | None = None) -> np.ndarray:
    """ICL-NUIM's final step ``z' = 35130 / round(35130 / round(z_cm) + N(0, 1) / 6 + 0.5)`` (in cm)."""
    depth = np.asarray(depth, dtype=np.float32)
    z_cm = np.round(depth.astype(np.float64) * 100.0)
    noise = rng.standard_normal(depth.shape) / 6.0
    with np.errstate(divide="ignore", invalid="ignore"):
        out = 35130.0 / np.round(35130.0 / z_cm + noise + 0.5) / 100.0
    return keep_missing(out, depth)


# --------------------------------------------------------------------------------------------------------
# parts: dropout and quantisation
# --------------------------------------------------------------------------------------------------------
def _drop(depth: np.ndarray, mask: np.ndarray, rng: np.random.Generator, probability: float) -> np.ndarray:
    """Zero ``depth`` where ``mask``, each pixel with ``probability`` (a draw is made for every pixel)."""
    u = rng.random(depth.shape, dtype=np.float32)
    return np.where(mask & (u < probability), 0.0, depth).astype(np.float32)


def range_limits(depth: np.ndarray, rng: np.random.Generator, *, z_min: float = 0.0, z_max: float = np.inf,
                 K: np.ndarray | None = None, rgb: np.ndarray | None = None) -> np.ndarray:
    """Zero depth outside the sensor's valid range ``[z_min, z_max]`` (metres)."""
    depth = np.asarray(depth, dtype=np.float32)
    return np.where((depth >= z_min) & (depth <= z_max), depth, 0.0).astype(np.float32)



def discontinuity_dropout(depth: np.ndarray, rng: np.random.Generator, *, threshold_m: float = 0.8,
                          window: int = 3, K: np.ndarray | None = None, rgb: np.ndarray | None = None) -> np.ndarray:
    """Zero depth where ``max - min`` of the valid depths in a ``window x window`` patch exceeds ``threshold_m``.

    Missing neighbours are ignored (a hole does not count as a discontinuity).
    """
    depth = np.asarray(depth, dtype=np.float32)
    kernel = np.ones((window, window), np.uint8)
    mx = cv2.dilate(depth, kernel, borderType=cv2.BORDER_REPLICATE)
    mn = cv2.erode(np.where(depth > 0, depth, np.float32(np.inf)), kernel, borderType=cv2.BORDER_REPLICATE)
    return np.where(mx - mn > threshold_m, 0.0, depth).astype(np.float32)


def edge_dropout(depth: np.ndarray, rng: np.random.Generator, *, threshold_m: float = 0.03, width_px: int = 2,
                 probability: float = 0.7, K: np.ndarray | None = None,
                 rgb: np.ndarray | None = None) -> np.ndarray:
    """Missing data along depth edges: pixels within ``width_px`` of a jump > ``threshold_m`` (between 4-
    neighbours, metres) are zeroed with ``probability``; holes are not edges."""
    depth = np.asarray(depth, dtype=np.float32)
    valid = depth > 0
    jump = np.zeros(depth.shape, dtype=bool)
    dv = np.abs(np.diff(depth, axis=0)) > threshold_m
    dv &= valid[1:] & valid[:-1]
    du = np.abs(np.diff(depth, axis=1)) > threshold_m
    du &= valid[:, 1:] & valid[:, :-1]
    jump[1:] |= dv
    jump[:-1] |= dv
    jump[:, 1:] |= du
    jump[:, :-1] |= du
    if width_px > 1:
        k = 2 * (int(width_px) - 1) + 1
        jump = cv2.dilate(jump.astype(np.uint8), np.ones((k, k), np.uint8)).astype(bool)
    return _drop(depth, jump, rng, probability)


def dark_dropout(depth: np.ndarray, rng: np.random.Generator, *, grey_threshold: float = 15.0,
                 probability: float = 1.0, K: np.ndarray | None = None,
                 rgb: np.ndarray | None = None) -> np.ndarray:
    """Zero depth on dark surfaces: grey level (0..255) of ``rgb`` below ``grey_threshold``. No-op without rgb."""
    depth = np.asarray(depth, dtype=np.float32)
    rgb = check_rgb(rgb, depth)
    if rgb is None:
        return depth.copy()
    grey = cv2.cvtColor(rgb, cv2.COLOR_RGB2GRAY)
    return _drop(depth, grey < grey_threshold, rng, probability)


def specular_dropout(depth: np.ndarray, rng: np.random.Generator, *, value_threshold: float = 250.0,
                     max_saturation: float = 0.15, grow_px: int = 1, probability: float = 1.0,
                     K: np.ndarray | None = None, rgb: np.ndarray | None = None) -> np.ndarray:
    """Zero depth on specular highlights: near-white, unsaturated ``rgb`` pixels (HSV value >=
    ``value_threshold`` of 255, saturation <= ``max_saturation``), grown by ``grow_px``. No-op without rgb."""
    depth = np.asarray(depth, dtype=np.float32)
    rgb = check_rgb(rgb, depth)
    if rgb is None:
        return depth.copy()
    v = rgb.max(axis=2).astype(np.float32)
    s = (v - rgb.min(axis=2)) / np.maximum(v, 1.0)
    spec = ((v >= value_threshold) & (s <= max_saturation)).astype(np.uint8)
    if grow_px > 0:
        spec = cv2.dilate(spec, np.ones((2 * grow_px + 1, 2 * grow_px + 1), np.uint8))
    return _drop(depth, spec.astype(bool), rng, probability)


def grazing_dropout(depth: np.ndarray, rng: np.random.Generator, *, start_deg: float = 75.0,
                    end_deg: float = 88.0, K: np.ndarray | None = None,
                    rgb: np.ndarray | None = None) -> np.ndarray:
    """Zero depth on grazing surfaces: drop probability ramps linearly from 0 at ``start_deg`` to 1 at
    ``end_deg`` of incidence angle (normal vs viewing ray)."""
    K = require_K(K, "grazing_dropout")
    depth = np.asarray(depth, dtype=np.float32)
    theta = np.rad2deg(incidence_angle(depth, K))
    p = np.clip((theta - start_deg) / max(end_deg - start_deg, 1e-6), 0.0, 1.0)
    u = rng.random(depth.shape, dtype=np.float32)
    return np.where(u < p, 0.0, depth).astype(np.float32)


def random_holes(depth: np.ndarray, rng: np.random.Generator, *, holes_per_megapixel: float = 60.0,
                 radius_px: tuple[float, float] = (1.0, 6.0), K: np.ndarray | None = None,
                 rgb: np.ndarray | None = None) -> np.ndarray:
    """Random elliptical holes: a Poisson number of ellipses (mean ``holes_per_megapixel`` per 1e6 px) with
    semi-axes uniform in ``radius_px`` (pixels) and random orientation are zeroed."""
    depth = np.asarray(depth, dtype=np.float32)
    h, w = depth.shape
    n = int(rng.poisson(holes_per_megapixel * h * w / 1e6))
    centres = rng.random((n, 2)) * (w, h)
    axes = rng.uniform(radius_px[0], radius_px[1], (n, 2))
    angles = rng.uniform(0.0, 180.0, n)
    mask = np.zeros((h, w), np.uint8)
    for (cx, cy), (a, b), ang in zip(centres, axes, angles):
        cv2.ellipse(mask, (int(cx), int(cy)), (max(1, int(round(a))), max(1, int(round(b)))), float(ang), 0, 360,
                    1, -1)
    return np.where(mask > 0, 0.0, depth).astype(np.float32)


def quantize_depth(depth: np.ndarray, rng: np.random.Generator, *, step_m: float = 0.001,
                   K: np.ndarray | None = None, rgb: np.ndarray | None = None) -> np.ndarray:
    """Round depth to multiples of ``step_m`` metres (deterministic; a value rounding to 0 becomes missing)."""
    depth = np.asarray(depth, dtype=np.float32)
    return keep_missing(np.round(depth / np.float32(step_m)) * np.float32(step_m), depth)
