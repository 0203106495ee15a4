"""Skins of the built-in objects: procedural textures drawn into each category's UV layout.

A skin (:class:`Skin`) is an sRGB albedo atlas with roughness and metallic maps, painted region by region of the
layouts of :mod:`simtest.objects.skin_uv` (which also maps a category's mesh into them: :func:`skin_uv`, re-exported
here). Textures: vectorized numpy from ``default_rng([seed, family index])``.
"""

from __future__ import annotations

import colorsys
import functools
from dataclasses import dataclass
from types import SimpleNamespace

import numpy as np
import trimesh

from simtest.errors import AssetError
from simtest.objects.skin_uv import CATEGORIES, INSET, LAYOUTS, SIDE_BANDS, WRAP, skin_uv

__all__ = ["SKIN_FAMILIES", "LAYOUTS", "SIDE_BANDS", "INSET", "WRAP", "Skin", "skin", "skin_uv"]

#: Category -> skin family.
SKIN_FAMILIES: dict[str, str] = {
    "can": "can_label", "bottle": "bottle_label", "mug": "ceramic", "bowl": "ceramic", "cup": "ceramic_printed",
    "box": "carton", "marker": "marker", "banana": "banana", "drill": "drill"}
assert set(SKIN_FAMILIES) == set(CATEGORIES)
_FAMILY_INDEX = {f: i for i, f in enumerate(sorted(set(SKIN_FAMILIES.values())))}

_WHITE, _DARK, _METAL = np.array([0.94, 0.93, 0.9]), np.array([0.07, 0.07, 0.08]), np.array([0.72, 0.72, 0.74])


@dataclass(frozen=True, eq=False)
class Skin:
    """The textures of one skin, all (S, S) with row 0 at the top, in one category's atlas layout.

    Attributes:
        albedo: (S, S, 3) uint8 sRGB base colour.
        roughness: (S, S) uint8, linear roughness * 255 (glaze ~0.15, paper label ~0.6, rubber ~0.8).
        metallic: (S, S) uint8, metallic * 255 (can lids and rims, the drill's chuck; 0 elsewhere).
        specular: Principled specular in [0, 1] of the whole skin.
    """

    albedo: np.ndarray
    roughness: np.ndarray
    metallic: np.ndarray
    specular: float


class _Region:
    """Texel coordinates ``s`` (right), ``t`` (up) of a region of a canvas (``size``, ``layout``, float maps ``rgb``,
    ``rough``, ``metal``) in the face-local units of :func:`_to_region` (slightly beyond 0..1 in the inset)."""

    def __init__(self, canvas: SimpleNamespace, name: str) -> None:
        size, (u0, v0, u1, v1), k = canvas.size, LAYOUTS[canvas.layout][name], 1 - 2 * INSET
        c0, c1, r0, r1 = round(u0 * size), round(u1 * size), round((1 - v1) * size), round((1 - v0) * size)
        u, v = (np.arange(c0, c1) + 0.5) / size, 1.0 - (np.arange(r0, r1) + 0.5) / size
        self.s, self.t = np.meshgrid(((u - u0) / (u1 - u0) - INSET) / k, ((v - v0) / (v1 - v0) - INSET) / k)
        self.canvas, self.window = canvas, (slice(r0, r1), slice(c0, c1))

    def mottle(self, colour, rng: np.random.Generator, amount: float = 0.04, alpha=True, x=None, **kw) -> None:
        """Paint ``colour`` varied smoothly in brightness and a little in hue (periodic in ``x``, default ``s``)."""
        x, colour = self.s if x is None else x, np.asarray(colour, dtype=np.float64)
        tone, hue = 1 + amount * _noise(x, self.t, rng), 3 * amount * _noise(x, self.t, rng)
        self.paint(alpha, (colour + hue[..., None] * (_shift(colour, 0.08) - colour)) * tone[..., None], **kw)

    def paint(self, alpha, colour, rough: float | None = None, metal: float | None = None) -> None:
        """Blend ``colour`` ((3,) or per texel) in where ``alpha`` (bool or 0..1, per texel) is set."""
        alpha, colour, c = np.asarray(alpha), np.asarray(colour, dtype=np.float64), self.canvas
        rgb = c.rgb[self.window]
        maps = [(v, m[self.window]) for v, m in ((rough, c.rough), (metal, c.metal)) if v is not None]
        if alpha.dtype == bool:  # a mask: assign where it is set (the cheap, common case)
            np.copyto(rgb, colour, where=alpha[..., None] if alpha.ndim else alpha)
            for value, view in maps:
                np.copyto(view, value, where=alpha)
            return
        a = np.broadcast_to(alpha.astype(np.float64), self.s.shape)
        rgb += a[..., None] * (colour - rgb)
        for value, view in maps:
            view += a * (value - view)


def _noise(x, y, rng: np.random.Generator, terms: int = 3, kmax: int = 4) -> np.ndarray:
    """Smooth noise of about unit amplitude from a few sinusoids, periodic with period 1 in ``x`` (a coordinate
    constant along an image axis is reduced along it: sin(A + B) from its parts)."""
    shape = np.broadcast(x, y).shape
    x, y = (np.broadcast_to(np.asarray(c, dtype=np.float64), shape) for c in (x, y))
    x, y = ((c[:1] if (c == c[:1]).all() else c[:, :1] if (c == c[:, :1]).all() else c) for c in (x, y))
    out = np.zeros(shape)
    for _ in range(terms):
        kx, ky, phase = int(rng.integers(1, kmax + 1)), float(rng.uniform(0, kmax)), rng.uniform(0, 2 * np.pi)
        p, q = 2 * np.pi * kx * x + phase, 2 * np.pi * ky * y
        out += np.sin(p) * np.cos(q) + np.cos(p) * np.sin(q) if x.shape != y.shape else np.sin(p + q)
    return out / np.sqrt(terms / 2.0)


def _box(x, y, x0, x1, y0, y1) -> np.ndarray:
    return (x >= x0) & (x < x1) & (y >= y0) & (y < y1)


def _glyphs(x, y, rng: np.random.Generator, box, rows: int, cells: int, fill: float = 0.8) -> np.ndarray:
    """Text-like rows of small rectangles (glyphs with word gaps) inside ``box = (x0, x1, y0, y1)``."""
    (x0, x1, y0, y1), mask = box, np.zeros(np.broadcast(x, y).shape, dtype=bool)
    inside, cx, line = _box(x, y, x0, x1, y0, y1), (x - x0) / (x1 - x0) * cells, (y1 - y0) / rows
    ci = np.clip(np.floor(cx).astype(np.int64), 0, cells - 1)
    for i in range(rows):
        on = (rng.random(cells) < fill) & (rng.random(cells) > 0.18)  # glyphs, with gaps between words
        on[int(cells * rng.uniform(0.55, 1.0)) if i == rows - 1 else cells:] = False  # short last line
        width, height = rng.uniform(0.45, 0.85, cells), rng.uniform(0.45, 0.75, cells)
        ly = (y1 - (i + 1) * line - y) / -line  # 0 at the line's bottom, 1 at its top
        mask |= inside & on[ci] & (cx - ci < width[ci]) & (ly >= 0.15) & (ly < 0.15 + height[ci])
    return mask


def _bars(x, y, rng: np.random.Generator, box, n: int = 36) -> tuple[np.ndarray, np.ndarray]:
    """A barcode: (white patch mask, black bars mask) in ``box = (x0, x1, y0, y1)``."""
    x0, x1, y0, y1 = box
    dx, dy = 0.08 * (x1 - x0), 0.12 * (y1 - y0)
    k = np.clip(np.floor((x - x0 - dx) / (x1 - x0 - 2 * dx) * n).astype(np.int64), 0, n - 1)
    return _box(x, y, *box), _box(x, y, x0 + dx, x1 - dx, y0 + dy, y1 - dy) & (rng.random(n) < 0.5)[k]


def _shift(rgb, hue: float = 0.0, sat: float = 1.0, val: float = 1.0) -> np.ndarray:
    """``rgb`` with its hue turned by ``hue`` and saturation / value scaled (clipped to [0, 1])."""
    h, s, v = colorsys.rgb_to_hsv(*np.clip(np.asarray(rgb, dtype=np.float64), 0, 1))
    return np.array(colorsys.hsv_to_rgb((h + hue) % 1.0, min(s * sat, 1.0), min(v * val, 1.0)))


def _accent(base, rng: np.random.Generator) -> np.ndarray:
    """A print colour that contrasts with ``base``: white, near black or a turned hue."""
    pick = int(rng.integers(3))
    if pick == 2 or max(base) - min(base) < 0.15:  # grey or white bases get a saturated accent
        return _shift((0.8, 0.2, 0.15), float(rng.uniform(0, 1)), 1.0, 0.95)
    return (_WHITE, _DARK * 2.0)[pick]


def _print_label(reg: _Region, a, h, base, rng: np.random.Generator, h0: float, h1: float, aspect: float) -> None:
    """A printed label on a side between heights ``h0`` and ``h1``: base-coloured ground, bands, a logo disk,
    a title and text rows on the front, a white panel with text and a barcode on the back."""
    lab, ell = (h >= h0) & (h <= h1), (h - h0) / (h1 - h0)
    reg.mottle(base, rng, 0.04, lab, a, rough=0.6, metal=0.0)
    front = float(rng.uniform(0, 1))
    da = (a - front + 0.5) % 1.0 - 0.5
    for _ in range(int(rng.integers(1, 4))):
        y, w, k = rng.uniform(0.05, 0.95), rng.uniform(0.03, 0.12), int(rng.integers(0, 3))
        wave = 0.04 * np.sin(2 * np.pi * k * a + rng.uniform(0, 6.3)) if rng.random() < 0.5 else 0.0
        reg.paint(lab & (np.abs(ell - y - wave) < w / 2), _accent(base, rng))
    accent = _accent(base, rng)
    r_logo, y_logo = rng.uniform(0.16, 0.26), rng.uniform(0.5, 0.68)
    d = np.hypot(da * aspect, ell - y_logo)
    reg.paint(lab & (d < r_logo), accent)
    reg.paint(lab & (d < r_logo * rng.uniform(0.45, 0.7)), _shift(base, float(rng.uniform(-0.1, 0.1)), 1, 0.8))
    title = (-0.22, 0.22, y_logo - r_logo - 0.2, y_logo - r_logo - 0.04)
    reg.paint(_glyphs(da, ell, rng, title, 1, int(rng.integers(5, 10)), 0.95), accent)
    back = (a - front) % 1.0 - 0.5
    reg.paint(lab & _box(back, ell, -0.11, 0.11, 0.1, 0.9), _WHITE)
    reg.paint(_glyphs(back, ell, rng, (-0.1, 0.1, 0.45, 0.86), int(rng.integers(4, 8)), 16), _DARK)
    for mask, colour in zip(_bars(back, ell, rng, (-0.09, 0.02, 0.14, 0.42)), (_WHITE, _DARK)):
        reg.paint(mask & lab, colour)


def _lid(canvas: SimpleNamespace, name: str, rng: np.random.Generator, colour=None) -> None:
    """A round lid, planar-mapped: metal (``colour`` None) or plastic, with concentric ridges."""
    reg = _Region(canvas, name)
    rr = np.hypot(reg.s - 0.5, reg.t - 0.5) * 2
    ridges = 1 - 0.18 * np.exp(-((rr - 0.78) / 0.03) ** 2) - 0.12 * np.exp(-((rr - 0.6) / 0.04) ** 2)
    reg.mottle(_METAL if colour is None else colour, rng, 0.05, rough=0.3 if colour is None else 0.45,
               metal=1.0 if colour is None else 0.0)
    reg.paint(True, canvas.rgb[reg.window] * ridges[..., None])


def _label_family(canvas: SimpleNamespace, base, rng: np.random.Generator, bottle: bool) -> None:
    """A can (metal with rolled rims and lids) or a plastic bottle (shoulder, ribbed cap), a printed label."""
    reg = _Region(canvas, "side")
    a, h = (reg.s * (1 + WRAP)) % 1.0, reg.t
    if not bottle:
        lo, hi = SIDE_BANDS["can"]
        reg.mottle(_METAL, rng, 0.05, rough=0.3, metal=1.0)
        reg.paint(np.abs(np.sin(np.pi * h / lo * 2)) < 0.3, _METAL * 0.75)  # rolled seams at both ends
        _print_label(reg, a, h, base, rng, lo + 0.03, hi - 0.03, aspect=2.5)
        for name in ("top", "bottom", "inside", "extra"):
            _lid(canvas, name, rng)
        return
    shoulder, _neck, cap_at = SIDE_BANDS["bottle"]
    plastic = base + (_WHITE - base) * rng.uniform(0.1, 0.35)
    cap = _shift(base, float(rng.choice([0.0, 0.33, 0.5])), 1.1, 0.7) if rng.random() < 0.6 else _WHITE
    reg.paint(True, plastic[None, None, :] * (1 + 0.05 * np.cos(2 * np.pi * 12 * h))[..., None], rough=0.25)
    _print_label(reg, a, h, base, rng, float(rng.uniform(0.1, 0.16)), shoulder - float(rng.uniform(0.04, 0.1)), 2.8)
    reg.paint(h > cap_at, cap, rough=0.5)
    reg.paint((h > cap_at) & (np.sin(2 * np.pi * 40 * a) > 0.6), cap * 0.82)  # the cap's grip ribs
    _lid(canvas, "top", rng, cap)
    for name in ("bottom", "inside", "extra"):
        _lid(canvas, name, rng, plastic)


def _ceramic(canvas: SimpleNamespace, base, rng: np.random.Generator, printed: bool) -> None:
    """Glazed mug / bowl (``printed`` False) or a printed cup: glossy glaze, darker rim, unglazed foot."""
    clay, glaze_r = np.array([0.78, 0.7, 0.58]) * rng.uniform(0.9, 1.05), float(rng.uniform(0.1, 0.2))
    rim = base * 0.55 if rng.random() < 0.6 else _shift(base, 0.08, 1.2, 0.45)
    reg = _Region(canvas, "side")
    a, h = (reg.s * (1 + WRAP)) % 1.0, reg.t
    reg.mottle(base, rng, 0.035, True, a, rough=0.45 if printed else glaze_r, metal=0.0)
    style = int(rng.integers(5)) if printed else int(rng.integers(6))
    if printed or style < 4:
        _decorate(reg, a, h, rng, style, _accent(base, rng), _accent(base, rng))
    reg.paint(h > 0.965, _WHITE if printed else rim)
    reg.paint(h < SIDE_BANDS["vessel"][0], _WHITE * 0.9 if printed else clay, rough=0.85)
    for name in ("inside", "extra"):
        _Region(canvas, name).mottle(base, rng, 0.03, rough=0.45 if printed else glaze_r, metal=0.0)
    _Region(canvas, "top").paint(True, _WHITE if printed else rim, rough=glaze_r)
    bottom = _Region(canvas, "bottom")
    rr = np.hypot(bottom.s - 0.5, bottom.t - 0.5) * 2
    bottom.paint(True, base, rough=glaze_r)
    bottom.paint((rr > 0.62) & (rr < 0.8), clay, rough=0.85)  # the unglazed foot ring
    bottom.paint(_glyphs(bottom.s, bottom.t, rng, (0.38, 0.62, 0.42, 0.58), 2, 6), base * 0.6)  # maker's stamp


def _decorate(reg: _Region, a, h, rng: np.random.Generator, style: int, c1, c2) -> None:
    """A painted or printed pattern on a vessel's side: band(s), dots, stripes, waves or a logo with text."""
    if style == 0:  # one or two painted bands
        for y in rng.uniform(0.25, 0.85, int(rng.integers(1, 3))):
            reg.paint(np.abs(h - y) < rng.uniform(0.03, 0.09), c1)
    elif style == 1:  # polka dots in staggered rows
        n, rows = int(rng.integers(8, 16)), int(rng.integers(3, 6))
        x = a * n + 0.5 * (np.floor(h * rows) % 2)
        d = np.hypot((x % 1.0) - 0.5, (h * rows % 1.0) - 0.5)
        reg.paint((d < rng.uniform(0.18, 0.32)) & (h > 0.1) & (h < 0.92), c1)
    elif style == 2:  # vertical or slanted stripes
        n, slant = int(rng.integers(6, 20)), float(rng.choice([0.0, 1.0, -1.0]))
        reg.paint(((a * n + slant * h) % 1.0) < rng.uniform(0.25, 0.5), c1)
    elif style == 3:  # waves
        k, y = int(rng.integers(2, 7)), float(rng.uniform(0.35, 0.7))
        reg.paint(np.abs(h - y - 0.08 * np.sin(2 * np.pi * k * a)) < 0.06, c1)
        reg.paint(np.abs(h - y + 0.2 - 0.05 * np.sin(2 * np.pi * k * a + 1)) < 0.03, c2)
    else:  # a logo disk and a line of text
        da = (a - float(rng.uniform(0, 1)) + 0.5) % 1.0 - 0.5
        d = np.hypot(da * 2.2, h - 0.58)
        reg.paint(d < 0.22, c1)
        reg.paint(d < 0.12, c2)
        reg.paint(_glyphs(da, h, rng, (-0.16, 0.16, 0.2, 0.32), 1, 8, 0.95), c1)


def _marker(canvas: SimpleNamespace, base, rng: np.random.Generator) -> None:
    reg = _Region(canvas, "side")
    a, h = (reg.s * (1 + WRAP)) % 1.0, reg.t
    tip_end, cap_at = SIDE_BANDS["marker"]
    ink = _shift(base, float(rng.uniform(-0.03, 0.03)), 1.05, float(rng.uniform(0.85, 1.1)))
    reg.paint(True, base, rough=0.4, metal=0.0)
    reg.paint(h < tip_end, np.array([0.85, 0.85, 0.83]), rough=0.5)
    reg.paint(h < 0.4 * tip_end, ink * 0.8, rough=0.9)  # the felt tip
    a0 = float(rng.uniform(0, 1))
    da = (a - a0 + 0.5) % 1.0 - 0.5
    lo, hi = tip_end + rng.uniform(0.06, 0.12), cap_at - rng.uniform(0.05, 0.12)
    band = (h > lo) & (h < hi) & (np.abs(da) < rng.uniform(0.25, 0.4))
    reg.paint(band, _WHITE, rough=0.6)
    text = (lo + 0.03, hi - 0.03, -0.2, 0.2)
    reg.paint(band & _glyphs(h, da, rng, text, int(rng.integers(2, 4)), 18), _DARK)
    reg.paint(band & (np.hypot((h - hi + 0.06) * 0.25, da) < 0.06), ink)
    reg.paint(h > cap_at, ink, rough=0.35)
    reg.paint((h > cap_at) & (np.abs(h - cap_at - 0.03) < 0.012), ink * 0.6)  # the cap's lip
    clip = (h > cap_at + 0.06) & (h < 0.97) & (np.abs((a - a0) % 1.0 - 0.5) < 0.05)
    reg.paint(clip, _shift(ink, 0, 0.9, 1.25))
    _lid(canvas, "top", rng, ink)
    _lid(canvas, "bottom", rng, ink * 0.8)


def _carton(canvas: SimpleNamespace, base, rng: np.random.Generator) -> None:
    """A printed cardboard box: panels, a product picture, titles and text on front and back, a nutrition
    panel on one side, a barcode on the other, plain cardboard on top and bottom."""
    board = np.array([0.66, 0.54, 0.4]) if rng.random() < 0.7 else np.array([0.9, 0.88, 0.83])
    food = _shift((0.75, 0.45, 0.2), float(rng.uniform(-0.08, 0.15)), rng.uniform(0.6, 1.1), rng.uniform(0.8, 1.1))
    accent, accent2 = _shift(base, float(rng.choice([-0.08, 0.08, 0.5])), 1.0, 0.6), _accent(base, rng)
    for face in ("front", "back"):
        reg = _Region(canvas, face)
        s, t = reg.s, reg.t
        reg.mottle(base, rng, 0.04, rough=0.6, metal=0.0)
        y_panel = float(rng.uniform(0.62, 0.78))
        reg.paint(np.abs(t - y_panel - 0.04 * np.sin(2 * np.pi * s)) < rng.uniform(0.06, 0.12), accent)
        reg.paint(_glyphs(s, t, rng, (0.1, 0.9, y_panel - 0.06, y_panel + 0.06), 1, int(rng.integers(5, 9)), 0.95),
                  accent2 if face == "front" else _DARK)
        cx, cy, rx = rng.uniform(0.35, 0.65), rng.uniform(0.25, 0.42), rng.uniform(0.18, 0.3)
        blob = np.hypot((s - cx) / rx, (t - cy) / (rx * 0.7) + 0.15 * np.sin(6 * s))
        shade = np.clip(1.25 - 0.6 * blob + 0.1 * _noise(s * 2, t * 2, rng), 0.4, 1.2)
        reg.paint(blob < 1, food[None, None, :] * shade[..., None])
        reg.paint(np.hypot((s - 0.85) / 0.1, (t - 0.92) / 0.06) < 1, accent2)  # corner badge
        reg.paint(_glyphs(s, t, rng, (0.08, 0.92, 0.03, 0.12), 2, 26), _WHITE if face == "front" else _DARK)
    right, left = _Region(canvas, "right"), _Region(canvas, "left")
    for reg in (right, left):
        reg.mottle(base, rng, 0.04, rough=0.6, metal=0.0)
    right.paint(_box(right.s, right.t, 0.1, 0.9, 0.15, 0.8), _WHITE)  # the nutrition panel
    right.paint(_box(right.s, right.t, 0.14, 0.86, 0.2, 0.75) & (np.abs((right.t * 40) % 1.0 - 0.5) < 0.08), _DARK)
    right.paint(_glyphs(right.s, right.t, rng, (0.14, 0.86, 0.2, 0.75), 10, 12), _DARK)
    left.paint(_glyphs(left.s, left.t, rng, (0.1, 0.9, 0.45, 0.85), 6, 12), _WHITE)
    for mask, colour in zip(_bars(left.s, left.t, rng, (0.2, 0.8, 0.08, 0.3)), (_WHITE, _DARK)):
        left.paint(mask, colour)
    for face in ("top", "bottom"):
        reg = _Region(canvas, face)
        reg.mottle(board, rng, 0.05, rough=0.75)
        reg.paint(np.abs(reg.t - 0.5) < 0.012, board * 0.7)  # the flaps' joint
        reg.paint((reg.t < 0.08) | (reg.t > 0.92), base)


def _banana(canvas: SimpleNamespace, base, rng: np.random.Generator) -> None:
    """Peel: yellow, green towards the ends and the ridges (less when riper, from the seed), brown speckles and
    bruises, dark tips, faint longitudinal ridges."""
    reg = _Region(canvas, "peel")
    s, t = reg.s, (reg.t * (1 + WRAP)) % 1.0
    ripe, end = float(rng.uniform(0.0, 1.0)), np.abs(s - 0.5) * 2
    ridge = np.cos(np.pi * 5 * t) ** 2  # 1 on the five ridges
    reg.mottle(base, rng, 0.05, x=t, rough=0.5, metal=0.0)
    reg.paint(np.clip((1.1 - ripe) * (0.9 * end ** 3 + 0.25 + 0.2 * ridge), 0, 1), np.array([0.42, 0.6, 0.16]))
    reg.paint(True, canvas.rgb[reg.window] * (1 - 0.12 * ridge)[..., None])
    n_s, n_t = 40, 24
    ci = np.clip(np.floor(s * n_s).astype(np.int64), 0, n_s - 1) * n_t + np.floor(t * n_t).astype(np.int64) % n_t
    on, ox, oy = rng.random(n_s * n_t) < ripe * 0.5 + 0.08, rng.random(n_s * n_t), rng.random(n_s * n_t)
    d = np.hypot((s * n_s % 1.0) - ox[ci], (t * n_t % 1.0) - oy[ci])
    brown = np.array([0.33, 0.21, 0.09])
    reg.paint(on[ci] & (d < rng.uniform(0.12, 0.4, n_s * n_t)[ci]), brown)
    reg.paint(np.clip((_noise(t, s * 3, rng, 6, 5) - 2.2 + ripe) * 2, 0, 0.7), brown * 1.3)  # bruises
    reg.paint(np.clip(1 - (1 - end) / 0.1, 0, 1), np.array([0.2, 0.14, 0.07]), rough=0.7)  # the tips


def _drill(canvas: SimpleNamespace, base, rng: np.random.Generator) -> None:
    """Two-tone plastic: coloured body, black rubber grip and battery, metal chuck, a small label."""
    grey = _DARK * float(rng.uniform(1.2, 2.4))
    body = _Region(canvas, "body")
    body.mottle(base, rng, 0.03, rough=0.35)
    body.paint(_box(body.s, body.t, 0.05, 0.3, 0.3, 0.7) & ((body.s * 24) % 1.0 < 0.4), grey)  # vents
    body.paint(_box(body.s, body.t, 0.45, 0.8, 0.35, 0.62), _DARK)
    body.paint(_glyphs(body.s, body.t, rng, (0.48, 0.77, 0.38, 0.59), 2, 8), base)
    handle = _Region(canvas, "handle")
    handle.paint(True, grey, rough=0.8)
    handle.paint((handle.t * 18) % 1.0 < 0.3, grey * 0.6)  # grip ridges
    handle.paint(handle.s < 0.4, base, rough=0.35)
    battery = _Region(canvas, "battery")
    battery.paint(True, grey * 0.8, rough=0.6)
    battery.paint((battery.t > 0.3) & (np.abs(battery.t - 0.8) > 0.05), base)
    battery.paint(_glyphs(battery.s, battery.t, rng, (0.2, 0.8, 0.15, 0.35), 1, 6), _WHITE * 0.7)
    chuck = _Region(canvas, "chuck")
    chuck.mottle(_METAL, rng, 0.05, rough=0.3, metal=1.0)
    chuck.paint((chuck.s * 30) % 1.0 < 0.35, _METAL * 0.6)  # knurling


@functools.lru_cache(maxsize=256)
def _skin_cached(category: str, base_rgb: tuple[float, float, float], seed: int, size: int) -> Skin:
    family = SKIN_FAMILIES[category]
    rng = np.random.default_rng([int(seed), _FAMILY_INDEX[family]])
    layout = {"carton": "carton", "banana": "banana", "drill": "drill"}.get(family, "revolution")
    canvas = SimpleNamespace(size=size, layout=layout, rgb=np.zeros((size, size, 3)), rough=np.full((size,) * 2, 0.6),
                             metal=np.zeros((size, size)))
    painters = {"can_label": lambda *a: _label_family(*a, False), "bottle_label": lambda *a: _label_family(*a, True),
                "ceramic": lambda *a: _ceramic(*a, False), "ceramic_printed": lambda *a: _ceramic(*a, True),
                "carton": _carton, "marker": _marker, "banana": _banana, "drill": _drill}
    painters[family](canvas, np.asarray(base_rgb, dtype=np.float64), rng)
    maps = [np.rint(np.clip(x, 0.0, 1.0) * 255.0).astype(np.uint8) for x in (canvas.rgb, canvas.rough, canvas.metal)]
    for arr in maps:
        arr.flags.writeable = False
    specular = {"ceramic": 0.6, "ceramic_printed": 0.5, "can_label": 0.5, "bottle_label": 0.55}.get(family, 0.4)
    return Skin(albedo=maps[0], roughness=maps[1], metallic=maps[2], specular=specular)


def skin(category: str, base_rgb: tuple[float, float, float], seed: int, size: int = 256) -> Skin:
    """The skin of one built-in category (cached; the same arguments give identical bytes).

    Args:
        category: A key of :data:`SKIN_FAMILIES`.
        base_rgb: Dominant sRGB colour of the print, each in [0, 1] (rounded to 4 digits).
        seed: Non-negative integer; picks the variant within the family (layout, bands, patterns, hues).
        size: Side of the square atlas, texels (>= 16).

    Raises:
        AssetError: Unknown category, a bad colour, seed or size.
    """
    if category not in SKIN_FAMILIES:
        raise AssetError(f"skin: unknown category {category!r}; known: {', '.join(SKIN_FAMILIES)}")
    rgb = tuple(round(float(c), 4) for c in base_rgb)
    if len(rgb) != 3 or not all(0.0 <= c <= 1.0 for c in rgb):
        raise AssetError(f"skin: base_rgb must be 3 values in [0, 1], got {base_rgb!r}")
    for name, value, low in (("seed", seed, 0), ("size (texels)", size, 16)):
        if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
            raise AssetError(f"skin: {name} must be an integer >= {low}, got {value!r}")
    return _skin_cached(category, rgb, int(seed), int(size))
