"""ImageNet-C digital corruptions (elastic transform, pixelate, JPEG, spatter), severities 1..5; see
:mod:`simtest.corrupt.weather`."""

from __future__ import annotations

import cv2
import numpy as np
from scipy import ndimage

from simtest.corrupt.image_ops import gaussian, to_float, to_uint8
from simtest.errors import ConfigError

__all__ = ["elastic_transform", "pixelate", "jpeg_compression", "spatter"]


def _smooth_noise(u: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian-filter white noise ``u`` (reflect border, truncate 3 sigma) quickly for large sigma.

    For large sigma the field is block-averaged by ``f`` first and filtered with ``sigma / f``: the block mean
    of white noise has variance ``var / f^2`` and filtering with ``sigma / f`` on the coarse grid restores the
    same output variance and correlation length, then it is upsampled bilinearly.
    """
    h, w = u.shape
    f = max(1, int(sigma // 4))
    if f == 1:
        return ndimage.gaussian_filter(u, sigma, mode="reflect", truncate=3.0)
    hc, wc = -(-h // f), -(-w // f)
    pad = np.pad(u, ((0, hc * f - h), (0, wc * f - w)), mode="reflect")
    coarse = pad.reshape(hc, f, wc, f).mean(axis=(1, 3))
    coarse = ndimage.gaussian_filter(coarse, sigma / f, mode="reflect", truncate=3.0)
    full = cv2.resize(coarse.astype(np.float32), (wc * f, hc * f), interpolation=cv2.INTER_LINEAR)
    return full[:h, :w]


def elastic_transform(image: np.ndarray, severity: int, rng: np.random.Generator) -> np.ndarray:
    """Elastic deformation: a random affine warp, then a smooth random displacement field.

    Parameters of the original ImageNet-C code (``make_imagenet_c.py``; its constant is 244, "should have been
    224"), as (alpha, sigma, affine) with every value multiplied by 244:
    (2, .7, .1), (2, .08, .2), (.05, .01, .02), (.07, .01, .02), (.12, .01, .02).
    The three reference points ``centre +- min(H, W) // 3`` move by ``U(-affine, affine)`` px
    (reflect-101 border); then ``dx, dy = alpha * gaussian(U(-1, 1), sigma)`` (reflect border, truncate 3)
    and bilinear resampling at ``(x + dx, y + dy)`` (reflect border).

    Size: the table is for 224 px. With ``s = min(H, W) / 224``, sigma and the affine range are multiplied by
    ``s`` and alpha by ``s^2`` (smoothed white noise has amplitude ~ 1 / sigma), so the displacement field in
    pixels and its correlation length both grow with ``s`` and the deformation looks the same relative to the
    image at every size.
    """
    base = [(2, 0.7, 0.1), (2, 0.08, 0.2), (0.05, 0.01, 0.02), (0.07, 0.01, 0.02), (0.12, 0.01, 0.02)]
    alpha, sigma, affine = (244.0 * v for v in base[severity - 1])
    x = to_float(image)
    h, w = x.shape[:2]
    s = min(h, w) / 224.0
    alpha, sigma, affine = alpha * s * s, sigma * s, affine * s

    center = np.float32([h, w]) // 2
    square = min(h, w) // 3
    pts1 = np.float32([center + square, [center[0] + square, center[1] - square], center - square])
    pts2 = pts1 + rng.uniform(-affine, affine, size=pts1.shape).astype(np.float32)
    M = cv2.getAffineTransform(pts1, pts2)
    x = cv2.warpAffine(x, M, (w, h), borderMode=cv2.BORDER_REFLECT_101).reshape(h, w, 3)

    dx = (_smooth_noise(rng.uniform(-1, 1, size=(h, w)), sigma) * alpha).astype(np.float32)
    dy = (_smooth_noise(rng.uniform(-1, 1, size=(h, w)), sigma) * alpha).astype(np.float32)
    gx, gy = np.meshgrid(np.arange(w, dtype=np.float32), np.arange(h, dtype=np.float32))
    out = cv2.remap(x, gx + dx, gy + dy, interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REFLECT)
    return to_uint8(out.reshape(h, w, 3))


def pixelate(image: np.ndarray, severity: int, rng: np.random.Generator) -> np.ndarray:
    """Pixelation: box (area) downsample by factor .6 .5 .4 .3 .25, nearest upsample. Deterministic."""
    c = [0.6, 0.5, 0.4, 0.3, 0.25][severity - 1]
    h, w = image.shape[:2]
    small = cv2.resize(image, (max(1, int(w * c)), max(1, int(h * c))), interpolation=cv2.INTER_AREA)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_NEAREST).reshape(image.shape)


def jpeg_compression(image: np.ndarray, severity: int, rng: np.random.Generator) -> np.ndarray:
    """JPEG re-encoding at quality 25 18 15 10 7 (libjpeg, 4:2:0 chroma as PIL's default). Deterministic."""
    q = [25, 18, 15, 10, 7][severity - 1]
    ok, buf = cv2.imencode(".jpg", cv2.cvtColor(image, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, q])
    if not ok:  # pragma: no cover - libjpeg failure
        raise ConfigError(f"JPEG encoding failed for an image of shape {image.shape}")
    return cv2.cvtColor(cv2.imdecode(buf, cv2.IMREAD_COLOR), cv2.COLOR_BGR2RGB)


def spatter(image: np.ndarray, severity: int, rng: np.random.Generator) -> np.ndarray:
    """Water or mud spatter on the lens (original ImageNet-C code; the paper's table gives no numbers).

    Parameters (loc, scale, sigma px, threshold, intensity, mud) per severity, as in ``make_imagenet_c.py``:
    (.65,.3,4,.69,.6,0) (.65,.3,3,.68,.6,0) (.65,.3,2,.68,.5,0) (.65,.3,1,.65,1.5,1) (.67,.4,1,.65,1.5,1).
    A Gaussian liquid layer ``N(loc, scale)`` is blurred by ``sigma`` and thresholded. Severities 1-3 (water):
    Canny edges of the layer -> distance transform (truncated at 20) -> blur, histogram equalisation and an
    emboss kernel give a drop-shading map ``m`` (normalised, times ``intensity``) and the result is
    ``x + m * paleturquoise (175, 238, 238)``. Severities 4-5 (mud): the thresholded layer blurred by
    ``intensity`` and cut below .8 is a mask ``m``; result ``x (1 - m) + m * brown (63, 42, 20)``.
    """
    loc, scale, sigma, thr, intensity, mud = [
        (0.65, 0.3, 4, 0.69, 0.6, 0),
        (0.65, 0.3, 3, 0.68, 0.6, 0),
        (0.65, 0.3, 2, 0.68, 0.5, 0),
        (0.65, 0.3, 1, 0.65, 1.5, 1),
        (0.67, 0.4, 1, 0.65, 1.5, 1),
    ][severity - 1]
    x = to_float(image)
    h, w = x.shape[:2]
    liquid = rng.standard_normal((h, w), dtype=np.float32) * np.float32(scale) + np.float32(loc)
    liquid = gaussian(liquid, sigma)
    liquid[liquid < thr] = 0
    if not mud:
        layer = (np.clip(liquid, 0, 1) * 255).astype(np.uint8)
        dist = 255 - cv2.Canny(layer, 50, 150)
        dist = cv2.distanceTransform(dist, cv2.DIST_L2, 5)
        _, dist = cv2.threshold(dist, 20, 20, cv2.THRESH_TRUNC)
        dist = cv2.blur(dist, (3, 3)).astype(np.uint8)
        dist = cv2.equalizeHist(dist)
        ker = np.array([[-2, -1, 0], [-1, 1, 1], [0, 1, 2]], dtype=np.float32)
        dist = cv2.filter2D(dist, cv2.CV_8U, ker)
        dist = cv2.blur(dist, (3, 3)).astype(np.float32)
        m = layer.astype(np.float32) * dist
        peak = float(m.max())
        m = (m / peak if peak > 0 else m) * np.float32(intensity)
        color = np.array([175, 238, 238], dtype=np.float32) / 255.0
        return to_uint8(x + m[..., None] * color)
    m = (liquid > thr).astype(np.float32)
    m = gaussian(m, intensity)
    m[m < 0.8] = 0
    color = np.array([63, 42, 20], dtype=np.float32) / 255.0
    return to_uint8(x * (1 - m[..., None]) + m[..., None] * color)
