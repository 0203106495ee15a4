"""2D paste occlusion at controlled levels (OccludedPASCAL3D+-style).

Textured occluders are pasted over the RGB image so that a requested fraction of the object (FG) and of the
background (BG) is covered. Depth is never touched, so a pasted occluder is visible in RGB only (the
RGB/depth inconsistency is part of this corruption; physical occluders placed in the simulated scene are the
other kind, measured from the renderer instead).

Two level definitions are supported; every result records which one it used:

* ``"pascal3d+"`` (OccludedPASCAL3D+ construction, Wang et al. 2020): L1 FG 20-40 %, BG 0-20 %;
  L2 FG 40-60 %, BG 20-40 %; L3 FG 60-80 %, BG 40-60 %.
* ``"objectcentric"`` (object-centred levels of large-scale occluded 3D benchmarks): targets L1 (10 %, 30 %),
  L2 (30 %, 50 %), L3 (50 %, 70 %) for (FG, BG); accepted bands are target +- 10 points, except the L1 FG
  band, which starts at 5 % so an L1 image is really occluded.

FG is the occluded fraction of the object mask, BG the occluded fraction of the non-object area. Placement
follows the reference construction: 1-3 occluders, the first centred on an object pixel (hence inside the
object's bounding box), every centre at least 25 px from the image border (``min(25, 10 %)`` of the short
side for small images), up to 40 random trials keeping the one closest to the target. Within a trial the
occluder sizes are solved by bisection (first occluder for FG, the others for BG) on a working copy of the
masks at most 256 px wide; the reported fractions are measured at full resolution.

Occluders are procedural star-shaped polygons or ellipses textured with either a crop cut from elsewhere in
the same image or a random colour-noise texture, or, when an ``occluder_bank`` is given, patches from it
(``(h, w, 4)`` RGBA with alpha > 127 as the shape, or ``(h, w, 3)`` RGB rectangles).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass
from typing import Any, Sequence

import cv2
import numpy as np

from simtest.corrupt.patches import bank_coverage, bank_size, blend_edge, resample
from simtest.errors import ConfigError
from simtest.io.bop import mask_bbox

__all__ = [
    "OCCLUSION_DEFINITIONS",
    "OCCLUSION_BANDS",
    "OcclusionInfo",
    "parse_occlusion_level",
    "paste_occluders",
    "update_visible_masks",
    "visibility_stats",
]

#: Level -> ((FG low, FG high), (BG low, BG high), (FG target, BG target)), fractions in [0, 1].
OCCLUSION_BANDS: dict[str, dict[int, tuple[tuple[float, float], tuple[float, float], tuple[float, float]]]] = {
    "pascal3d+": {
        1: ((0.2, 0.4), (0.0, 0.2), (0.3, 0.1)),
        2: ((0.4, 0.6), (0.2, 0.4), (0.5, 0.3)),
        3: ((0.6, 0.8), (0.4, 0.6), (0.7, 0.5)),
    },
    "objectcentric": {
        1: ((0.05, 0.2), (0.2, 0.4), (0.1, 0.3)),
        2: ((0.2, 0.4), (0.4, 0.6), (0.3, 0.5)),
        3: ((0.4, 0.6), (0.6, 0.8), (0.5, 0.7)),
    },
}
OCCLUSION_DEFINITIONS: tuple[str, ...] = tuple(OCCLUSION_BANDS)

_MAX_TRIALS = 40
_WORK_SIDE = 256
_BISECT_STEPS = 14


@dataclass(frozen=True)
class OcclusionInfo:
    """What a paste achieved.

    Attributes:
        level: Requested level 0..3.
        definition: ``"pascal3d+"`` or ``"objectcentric"``.
        fg_fraction: Occluded fraction of the object mask (0 if the mask is empty).
        bg_fraction: Occluded fraction of the non-object area.
        fg_band, bg_band: The accepted bands for this level and definition.
        in_band: Both fractions inside their bands.
        n_occluders: Number of pasted occluders.
        trials: Placement trials used (<= 40).
        object_pixels: Pixels in the object mask.
        kinds: Texture of each occluder: ``"crop"``, ``"noise"`` or ``"bank"``.
        centers: Occluder centres ``(x, y)`` in pixels, the first one on the object.
        margin: Minimum distance of the centres from the image border (pixels).
    """

    level: int
    definition: str
    fg_fraction: float
    bg_fraction: float
    fg_band: tuple[float, float]
    bg_band: tuple[float, float]
    in_band: bool
    n_occluders: int
    trials: int
    object_pixels: int
    kinds: tuple[str, ...] = ()
    centers: tuple[tuple[float, float], ...] = ()
    margin: int = 0

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["fg_band"], d["bg_band"], d["kinds"] = list(self.fg_band), list(self.bg_band), list(self.kinds)
        d["centers"] = [list(c) for c in self.centers]
        return d


def parse_occlusion_level(level: int | str) -> int:
    """``0..3`` from an int or a name ``"L0".."L3"`` (case-insensitive); :class:`ConfigError` otherwise."""
    value: Any = level
    if isinstance(level, str):
        s = level.strip().upper()
        value = int(s[1:]) if len(s) == 2 and s[0] == "L" and s[1].isdigit() else None
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 0 <= value <= 3:
        raise ConfigError(f"occlusion level must be one of L0, L1, L2, L3 (or 0..3), got {level!r}")
    return int(value)


def _check_definition(definition: str) -> str:
    if definition not in OCCLUSION_BANDS:
        raise ConfigError(f"unknown occlusion definition {definition!r}; valid: {', '.join(OCCLUSION_DEFINITIONS)}")
    return definition


# --------------------------------------------------------------------------------------------------------
# occluder shapes
# --------------------------------------------------------------------------------------------------------
@dataclass
class _Shape:
    """An occluder shape in unit size (characteristic radius 1) around its centre ``(cx, cy)`` (pixels)."""

    cx: float
    cy: float
    poly: np.ndarray | None = None  # (K, 2) unit vertices, star-shaped around the centre
    alpha: np.ndarray | None = None  # bank shape, bool (h, w); the longer side spans 2 units
    bank_index: int = -1

    def mask(self, shape: tuple[int, int], scale: float, f: float = 1.0) -> np.ndarray:
        """Rasterise at radius ``scale`` px (full resolution) on a canvas ``shape`` drawn at resolution ``f``."""
        h, w = shape
        out = np.zeros((h, w), np.uint8)
        r = scale * f
        if r <= 0:
            return out
        cx, cy = self.cx * f, self.cy * f
        if self.poly is not None:
            pts = np.rint((self.poly * r + (cx, cy)) * 16).astype(np.int32)
            cv2.fillPoly(out, [pts], 1, cv2.LINE_8, 4)
            return out
        a = (bank_coverage(self.alpha, r) >= 0.5).astype(np.uint8)
        ph, pw = a.shape
        x0, y0 = int(round(cx - pw / 2)), int(round(cy - ph / 2))
        xs0, ys0 = max(x0, 0), max(y0, 0)
        xs1, ys1 = min(x0 + pw, w), min(y0 + ph, h)
        if xs1 > xs0 and ys1 > ys0:
            out[ys0:ys1, xs0:xs1] = a[ys0 - y0:ys1 - y0, xs0 - x0:xs1 - x0]
        return out


def _random_poly(rng: np.random.Generator) -> np.ndarray:
    """Unit star-shaped polygon: an ellipse (random aspect, rotation) or a random 5-12-gon."""
    if rng.random() < 0.5:
        t = np.linspace(0, 2 * np.pi, 36, endpoint=False)
        a = rng.uniform(0.5, 1.0)
        pts = np.stack([np.cos(t), a * np.sin(t)], axis=1)
    else:
        k = int(rng.integers(5, 13))
        t = np.sort(rng.uniform(0, 2 * np.pi, k))
        rad = rng.uniform(0.55, 1.0, k)
        pts = np.stack([rad * np.cos(t), rad * np.sin(t)], axis=1)
    rot = rng.uniform(0, 2 * np.pi)
    R = np.array([[np.cos(rot), -np.sin(rot)], [np.sin(rot), np.cos(rot)]])
    pts = pts @ R.T
    return pts / np.sqrt(np.abs(_poly_area(pts)) / np.pi)  # unit-circle area


def _poly_area(p: np.ndarray) -> float:
    x, y = p[:, 0], p[:, 1]
    return 0.5 * float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1)))


def _noise_texture(h: int, w: int, rng: np.random.Generator) -> np.ndarray:
    """Random colour texture ``(h, w, 3)`` uint8: a smooth colour field with blotches and fine grain."""
    base = rng.uniform(0, 255, 3)
    cells = int(rng.integers(2, 8))
    grid = rng.normal(0, 60, (cells, cells, 3)).astype(np.float32)
    tex = cv2.resize(grid, (w, h), interpolation=cv2.INTER_CUBIC).reshape(h, w, 3) + base.astype(np.float32)
    fine = rng.normal(0, rng.uniform(5, 30), (h, w, 1)).astype(np.float32)
    return np.clip(tex + fine, 0, 255).astype(np.uint8)


# --------------------------------------------------------------------------------------------------------
# placement
# --------------------------------------------------------------------------------------------------------
def _band_distance(x: float, band: tuple[float, float]) -> float:
    return max(band[0] - x, 0.0, x - band[1])


def _fractions(occ: np.ndarray, obj: np.ndarray, n_obj: int, n_bg: int) -> tuple[float, float]:
    o = occ.astype(bool)
    fg_hit = int(np.count_nonzero(o & obj))
    bg_hit = int(np.count_nonzero(o)) - fg_hit
    return (fg_hit / n_obj if n_obj else 0.0), (bg_hit / n_bg if n_bg else 0.0)


def _union(shapes: Sequence[_Shape], scales: Sequence[float], shape: tuple[int, int], f: float) -> np.ndarray:
    out = np.zeros(shape, np.uint8)
    for s, r in zip(shapes, scales):
        out |= s.mask(shape, r, f)
    return out


def _bisect(fn, target: float, hi: float) -> float:
    """Smallest-ish ``x`` in ``[0, hi]`` with ``fn(x) >= target`` (``fn`` non-decreasing)."""
    lo = 0.0
    if fn(hi) < target:
        return hi
    for _ in range(_BISECT_STEPS):
        mid = 0.5 * (lo + hi)
        if fn(mid) < target:
            lo = mid
        else:
            hi = mid
    return hi


class _PointSampler:
    """Draws random pixels (x, y) of a mask, at least ``margin`` px from the border, optionally with
    probability proportional to ``weight``; the candidate list and CDF are computed once."""

    def __init__(self, mask: np.ndarray, margin: int, weight: np.ndarray | None = None) -> None:
        h, w = mask.shape
        m = np.zeros_like(mask, dtype=bool)
        m[margin:h - margin, margin:w - margin] = mask[margin:h - margin, margin:w - margin]
        self.ys, self.xs = np.nonzero(m)
        self.cdf = None
        if weight is not None and len(self.xs):
            c = np.cumsum(weight[self.ys, self.xs].astype(np.float64))
            if c[-1] > 0:
                self.cdf = c / c[-1]

    def __bool__(self) -> bool:
        return len(self.xs) > 0

    def __call__(self, rng: np.random.Generator) -> tuple[float, float]:
        if self.cdf is not None:
            i = min(int(np.searchsorted(self.cdf, rng.random(), side="right")), len(self.xs) - 1)
        else:
            i = int(rng.integers(len(self.xs)))
        return float(self.xs[i]), float(self.ys[i])


def _check_bank(bank: Sequence[np.ndarray]) -> list[tuple[np.ndarray, np.ndarray]]:
    out = []
    for i, patch in enumerate(bank):
        p = np.asarray(patch)
        if p.dtype != np.uint8 or p.ndim != 3 or p.shape[2] not in (3, 4) or min(p.shape[:2]) < 1:
            raise ConfigError(f"occluder_bank[{i}] must be an (h, w, 3) RGB or (h, w, 4) RGBA uint8 array, got "
                              f"{p.dtype} {p.shape}")
        alpha = p[..., 3] > 127 if p.shape[2] == 4 else np.ones(p.shape[:2], bool)
        if not alpha.any():
            raise ConfigError(f"occluder_bank[{i}] has an empty alpha mask")
        out.append((np.ascontiguousarray(p[..., :3]), alpha))
    if not out:
        raise ConfigError("occluder_bank is empty; pass None for procedural occluders")
    return out


def paste_occluders(
    rgb: np.ndarray,
    object_mask: np.ndarray,
    level: int | str,
    rng: np.random.Generator,
    occluder_bank: Sequence[np.ndarray] | None = None,
    definition: str = "pascal3d+",
) -> tuple[np.ndarray, np.ndarray, OcclusionInfo]:
    """Paste 1-3 textured occluders so the object and background are covered at the requested level.

    Args:
        rgb: ``(H, W, 3)`` uint8 image.
        object_mask: ``(H, W)`` bool (or 0/255) mask of the object(s) whose occlusion is controlled, usually
            the union of the visible masks.
        level: ``0..3`` or ``"L0".."L3"``; level 0 returns an unchanged copy.
        rng: Source of all randomness.
        occluder_bank: Optional RGBA/RGB uint8 patches used as occluders instead of procedural shapes.
        definition: ``"pascal3d+"`` or ``"objectcentric"`` (see the module docstring for the bands).

    Returns:
        ``(rgb_out, occluder_mask, info)``: the new image, the ``(H, W)`` bool union of pasted pixels, and an
        :class:`OcclusionInfo` with the achieved FG/BG fractions. If no trial lands in both bands the closest
        one is used and ``info.in_band`` is False.

    Raises:
        ConfigError: Bad level, definition, image/mask shapes or bank entries.
    """
    lvl = parse_occlusion_level(level)
    definition = _check_definition(definition)
    rgb = np.asarray(rgb)
    if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ConfigError(f"rgb must be an (H, W, 3) uint8 array, got {rgb.dtype} {rgb.shape}")
    obj = np.asarray(object_mask).astype(bool)
    if obj.shape != rgb.shape[:2]:
        raise ConfigError(f"object_mask shape {obj.shape} does not match the image {rgb.shape[:2]}")
    bank = _check_bank(occluder_bank) if occluder_bank is not None else None
    h, w = obj.shape
    n_obj = int(obj.sum())
    n_bg = h * w - n_obj
    if lvl == 0:
        info = OcclusionInfo(0, definition, 0.0, 0.0, (0.0, 0.0), (0.0, 0.0), True, 0, 0, n_obj)
        return rgb.copy(), np.zeros((h, w), bool), info
    fg_band, bg_band, _ = OCCLUSION_BANDS[definition][lvl]
    margin = int(min(25, max(0, int(0.1 * min(h, w)))))
    shapes, scales, trials = _search_occluders(obj, OCCLUSION_BANDS[definition][lvl], margin, bank, rng)
    out, occ, kinds = _paint_occluders(rgb, obj, shapes, scales, bank, rng)
    fg, bg = _fractions(occ, obj, n_obj, n_bg)
    info = OcclusionInfo(
        level=lvl, definition=definition, fg_fraction=float(fg), bg_fraction=float(bg), fg_band=fg_band,
        bg_band=bg_band, in_band=_band_distance(fg, fg_band) == 0 and _band_distance(bg, bg_band) == 0,
        n_occluders=len(shapes), trials=trials, object_pixels=n_obj, kinds=tuple(kinds),
        centers=tuple((float(sh.cx), float(sh.cy)) for sh in shapes), margin=margin,
    )
    return out, occ, info


def _occluder_centre(i: int, obj: np.ndarray, n_obj: int, margin: int, samplers: tuple,
                     rng: np.random.Generator) -> tuple[float, float]:
    """Centre (x, y) of occluder ``i``: the first on the object, the others preferably on the background."""
    h, w = obj.shape
    obj_points, bg_points, any_points = samplers
    if i == 0 and n_obj:
        if obj_points:
            return obj_points(rng)
        # object entirely within the margin: clamp an object pixel into it
        ys, xs = np.nonzero(obj)
        j = int(rng.integers(len(xs)))
        return float(np.clip(xs[j], margin, w - 1 - margin)), float(np.clip(ys[j], margin, h - 1 - margin))
    if bg_points:
        return bg_points(rng)
    if any_points:
        return any_points(rng)
    return (w - 1) / 2, (h - 1) / 2


def _search_occluders(obj: np.ndarray, bands: tuple, margin: int, bank, rng: np.random.Generator
                      ) -> tuple[list[_Shape], list[float], int]:
    """Random occluder layouts, each sized by bisection to the level's targets, until one lands in both bands
    (else the closest of :data:`_MAX_TRIALS`). Returns ``(shapes, scales in pixels, trials)``."""
    fg_band, bg_band, (fg_t, bg_t) = bands
    h, w = obj.shape
    n_obj = int(obj.sum())
    # working resolution for the size search
    f = min(1.0, _WORK_SIDE / max(h, w))
    wh, ww = max(1, int(round(h * f))), max(1, int(round(w * f)))
    f_eff = ww / w
    obj_w = cv2.resize(obj.astype(np.uint8), (ww, wh), interpolation=cv2.INTER_NEAREST).astype(bool)
    n_obj_w = int(obj_w.sum())
    n_bg_w = ww * wh - n_obj_w
    if n_obj and not n_obj_w:  # tiny object lost by the downscale: search at full resolution
        f_eff, wh, ww, obj_w, n_obj_w, n_bg_w = 1.0, h, w, obj, n_obj, h * w - n_obj
    hi = float(np.hypot(h, w))
    # background occluders are centred preferably far from the object (probability ~ squared distance)
    far = cv2.distanceTransform((~obj).astype(np.uint8), cv2.DIST_L2, 3) ** 2 if n_obj else None
    samplers = (_PointSampler(obj, margin), _PointSampler(~obj, margin, far),
                _PointSampler(np.ones((h, w), bool), margin))

    best: tuple[float, list[_Shape], list[float], int] | None = None
    trials = 0
    for trials in range(1, _MAX_TRIALS + 1):
        n = int(rng.integers(1, 4))
        shapes: list[_Shape] = []
        for i in range(n):
            pt = _occluder_centre(i, obj, n_obj, margin, samplers, rng)
            if bank is not None:
                k = int(rng.integers(len(bank)))
                shapes.append(_Shape(pt[0], pt[1], alpha=bank[k][1], bank_index=k))
            else:
                shapes.append(_Shape(pt[0], pt[1], poly=_random_poly(rng)))
        # relative sizes of the background occluders
        rel = [1.0] + [float(rng.uniform(0.5, 1.5)) for _ in range(n - 1)]

        def frac(sa: float, sb: float) -> tuple[float, float]:
            scales = [sa] + [sb * r for r in rel[1:]]
            return _fractions(_union(shapes, scales, (wh, ww), f_eff), obj_w, n_obj_w, n_bg_w)

        sa, sb = 0.0, 0.0
        if n_obj:
            sa = _bisect(lambda s: frac(s, sb)[0], fg_t, hi)
            for _ in range(3 if n > 1 else 0):
                sb = _bisect(lambda s: frac(sa, s)[1], bg_t, hi) if frac(sa, 0.0)[1] < bg_t else 0.0
                sa = _bisect(lambda s: frac(s, sb)[0], fg_t, hi)
        else:
            sa = _bisect(lambda s: frac(s, s)[1], bg_t, hi)
            sb = sa
        fg, bg = frac(sa, sb)
        # the FG band (the object's occlusion) has priority over the BG band, then closeness to the targets
        score = (20.0 * _band_distance(fg, fg_band) + 10.0 * _band_distance(bg, bg_band)
                 + abs(fg - fg_t) + abs(bg - bg_t))
        if best is None or score < best[0]:
            best = (score, shapes, [sa] + [sb * r for r in rel[1:]], trials)
        if _band_distance(fg, fg_band) == 0 and _band_distance(bg, bg_band) == 0:
            break
    assert best is not None
    return best[1], best[2], trials


def _paint_occluders(rgb: np.ndarray, obj: np.ndarray, shapes: list[_Shape], scales: list[float], bank,
                     rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Paint the occluders at full resolution: ``(image, union mask of pasted pixels, texture kind each)``."""
    h, w = obj.shape
    out = rgb.copy()
    occ = np.zeros((h, w), bool)
    kinds: list[str] = []
    for shp, r in zip(shapes, scales):
        m = shp.mask((h, w), r, 1.0).astype(bool)
        if not m.any():
            kinds.append("none")
            continue
        ys, xs = np.nonzero(m)
        y0, y1, x0, x1 = ys.min(), ys.max() + 1, xs.min(), xs.max() + 1
        bh, bw = y1 - y0, x1 - x0
        if bank is not None:
            ph, pw = bank_size(shp.alpha.shape, r)
            tex_full = resample(bank[shp.bank_index][0], (ph, pw))
            px0, py0 = int(round(shp.cx - pw / 2)), int(round(shp.cy - ph / 2))
            tex = tex_full[y0 - py0:y1 - py0, x0 - px0:x1 - px0]
            kinds.append("bank")
            blend_edge(out, m, tex_full, (py0, px0))
        elif rng.random() < 0.5 and (bh < h or bw < w):
            tex = _image_crop(rgb, obj, bh, bw, rng)
            kinds.append("crop")
        else:
            tex = _noise_texture(bh, bw, rng)
            kinds.append("noise")
        sub = m[y0:y1, x0:x1]
        out[y0:y1, x0:x1][sub] = tex[sub]
        occ |= m
    return out, occ, kinds


def _image_crop(rgb: np.ndarray, obj: np.ndarray, bh: int, bw: int, rng: np.random.Generator) -> np.ndarray:
    """A ``(bh, bw)`` crop cut from elsewhere in the image (least object overlap of 5 candidates), randomly
    flipped; resized from the whole image if the crop does not fit."""
    h, w = obj.shape
    if bh > h or bw > w:
        return cv2.resize(rgb, (bw, bh), interpolation=cv2.INTER_LINEAR)
    ii = cv2.integral(obj.astype(np.uint8))
    best, best_cost = (0, 0), None
    for _ in range(5):
        y = int(rng.integers(0, h - bh + 1))
        x = int(rng.integers(0, w - bw + 1))
        cost = int(ii[y + bh, x + bw] - ii[y, x + bw] - ii[y + bh, x] + ii[y, x])
        if best_cost is None or cost < best_cost:
            best, best_cost = (y, x), cost
    y, x = best
    crop = rgb[y:y + bh, x:x + bw]
    if rng.random() < 0.5:
        crop = crop[:, ::-1]
    if rng.random() < 0.5:
        crop = crop[::-1]
    return np.ascontiguousarray(crop)


# --------------------------------------------------------------------------------------------------------
# visible masks
# --------------------------------------------------------------------------------------------------------
def update_visible_masks(masks_visib: Sequence[np.ndarray] | np.ndarray,
                         occluder_mask: np.ndarray) -> list[np.ndarray]:
    """Visible masks after a paste: ``mask_visib & ~occluder_mask`` for each mask.

    Args:
        masks_visib: One ``(H, W)`` mask or a sequence (or ``(N, H, W)`` stack) of them, bool or 0/255.
        occluder_mask: ``(H, W)`` bool mask of pasted pixels.

    Returns:
        A list of ``(H, W)`` bool masks (one per input mask).
    """
    occ = np.asarray(occluder_mask).astype(bool)
    arr = masks_visib if not isinstance(masks_visib, np.ndarray) or masks_visib.ndim == 3 else [masks_visib]
    out = []
    for m in arr:
        m = np.asarray(m).astype(bool)
        if m.shape != occ.shape:
            raise ConfigError(f"visible mask shape {m.shape} does not match the occluder mask {occ.shape}")
        out.append(m & ~occ)
    return out


def visibility_stats(mask_visib: np.ndarray, px_count_all: int) -> dict[str, Any]:
    """BOP ``scene_gt_info`` visibility fields of a visible mask.

    Args:
        mask_visib: ``(H, W)`` visible mask.
        px_count_all: Pixels of the full (amodal, untruncated) silhouette, as in ``scene_gt_info.json``.

    Returns:
        ``{"px_count_visib", "visib_fract", "bbox_visib"}`` with ``visib_fract = px_count_visib /
        px_count_all`` (0 if ``px_count_all`` is 0) and ``bbox_visib = [x, y, w, h]`` in pixels, BOP's box
        (:func:`simtest.io.bop.mask_bbox`; ``[-1, -1, -1, -1]`` when nothing is visible).
    """
    m = np.asarray(mask_visib).astype(bool)
    n = int(m.sum())
    return {"px_count_visib": n, "visib_fract": float(n / px_count_all) if px_count_all > 0 else 0.0,
            "bbox_visib": mask_bbox(m)}
