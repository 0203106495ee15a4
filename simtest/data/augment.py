"""Training augmentations: seeded image corruptions, paste occluders and depth noise applied to samples of
:class:`simtest.data.PoseDataset` (see :func:`augmentation`)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import cv2
import numpy as np

from simtest.errors import ConfigError

__all__ = ["Corrupt", "RandomCorrupt", "ColorJitter", "ObjectLight", "BackgroundSwap", "Compose", "augmentation", "TRAIN_WEATHER", "AUGMENTATIONS"]

#: Image corruptions used by the ``weather`` augmentation. The four evaluation conditions of the robustness
#: tables (brightness, frost, snow, fog) are deliberately left out so they stay unseen in training.
TRAIN_WEATHER: tuple[str, ...] = ("gaussian_noise", "shot_noise", "defocus_blur", "motion_blur", "contrast",
                                  "saturate", "jpeg_compression", "pixelate", "gaussian_blur", "spatter")
#: Names understood by :func:`augmentation`.
AUGMENTATIONS: tuple[str, ...] = ("occlusion", "weather", "depth", "color", "background", "object-light")


@dataclass(frozen=True)
class Corrupt:
    """Apply one :class:`simtest.corrupt.CorruptionSpec` with probability ``p``.

    A paste occlusion is controlled on the union of the visible masks, and the visible masks are updated.
    """

    spec: Any
    p: float = 1.0

    def __call__(self, sample: dict[str, Any], rng: np.random.Generator) -> dict[str, Any]:
        from simtest.corrupt import update_visible_masks

        if rng.random() >= self.p or self.spec.is_identity:
            return sample
        masks = sample["masks"]
        use_masks = masks if len(masks) else np.zeros((1,) + sample["rgb"].shape[:2], bool)
        rgb, depth, occ = self.spec.apply(sample["rgb"], sample["depth"], use_masks, rng, sample["K"])
        out = dict(sample, rgb=rgb, depth=depth)
        if occ.any() and len(masks):
            out["masks"] = np.stack(update_visible_masks(masks, occ))
        return out


@dataclass(frozen=True)
class RandomCorrupt:
    """Pick one of several corruption kinds per sample (with probability ``p``) at a random severity / level.

    Attributes:
        weather: Image corruption names to choose from (empty: none).
        severities: Severities to choose from.
        occlusion_levels: Paste-occlusion levels to choose from (empty: none).
        depth_noise: Depth presets to choose from (empty: none).
        p: Probability of corrupting a sample at all; each kind is then applied independently with
            probability ``p_each``.
        p_each: See ``p``.
    """

    weather: tuple[str, ...] = ()
    severities: tuple[int, ...] = (1, 2, 3, 4, 5)
    occlusion_levels: tuple[int, ...] = ()
    depth_noise: tuple[str, ...] = ()
    p: float = 1.0
    p_each: float = 0.5

    def __call__(self, sample: dict[str, Any], rng: np.random.Generator) -> dict[str, Any]:
        from simtest.corrupt import CorruptionSpec

        r_gate, r_kind, r_apply = rng.spawn(3)
        if r_gate.random() >= self.p:
            return sample
        draws = r_kind.random(3)
        picks = r_kind.integers(0, 1 << 30, size=4)
        kw: dict[str, Any] = {}
        if self.weather and draws[0] < self.p_each:
            kw["weather"] = self.weather[picks[0] % len(self.weather)]
            kw["severity"] = int(self.severities[picks[1] % len(self.severities)])
        if self.occlusion_levels and draws[1] < self.p_each:
            kw["occlusion"] = int(self.occlusion_levels[picks[2] % len(self.occlusion_levels)])
            kw["occlusion_kind"] = "paste"  # a training sample carries no cutout library: noise and crop shapes
        if self.depth_noise and draws[2] < self.p_each:
            kw["depth_noise"] = self.depth_noise[picks[3] % len(self.depth_noise)]
        if not kw:
            return sample
        return Corrupt(CorruptionSpec(**kw))(sample, r_apply)


@dataclass(frozen=True)
class ColorJitter:
    """Photometric jitter of the RGB image, for transfer to real cameras (with probability ``p``): in order a
    per-channel gain (white balance), brightness gain, contrast about the image mean, saturation about the
    grey value, then a gamma; each factor uniform in ``[1 - x, 1 + x]`` for its amplitude ``x`` (gamma:
    ``exp(U(-x, x))``). Geometry, depth and masks are untouched.

    It overlaps the ``brightness`` condition of the robustness tables, so it is not in the default training
    augmentation (name it: ``--augment occlusion,weather,color``).
    """

    gain: float = 0.12
    brightness: float = 0.35
    contrast: float = 0.3
    saturation: float = 0.4
    gamma: float = 0.25
    p: float = 0.8

    def __call__(self, sample: dict[str, Any], rng: np.random.Generator) -> dict[str, Any]:
        u = rng.uniform(-1.0, 1.0, size=7)
        if rng.random() >= self.p:
            return sample
        x = np.asarray(sample["rgb"], np.float32) / np.float32(255.0)
        x = x * (1.0 + self.gain * u[:3]).astype(np.float32) * np.float32(1.0 + self.brightness * u[3])
        mean = x.mean()
        x = (x - mean) * np.float32(1.0 + self.contrast * u[4]) + mean
        grey = x @ np.array([0.299, 0.587, 0.114], np.float32)
        x = (x - grey[..., None]) * np.float32(1.0 + self.saturation * u[5]) + grey[..., None]
        x = np.clip(x, 0.0, 1.0) ** np.float32(np.exp(self.gamma * u[6]))
        return dict(sample, rgb=np.round(x * 255.0).astype(np.uint8))


@dataclass(frozen=True)
class ObjectLight:
    """Brighten (or dim) each annotated object's visible pixels by a gain of its own, uniform in ``gain``
    (sRGB values multiplied and clipped; with probability ``p`` per sample). Geometry, depth and masks are
    untouched; distractors and the room keep their rendered values.

    Why: a real camera can show the objects lit brighter against their surroundings than a render does. On
    LM-O's 100 real frames the objects' visible pixels average 0.72 of their models' vertex colours, in
    ``configs/lmo-clutter.toml``'s path-traced frames 0.50, at about the same image mean; a global brightness
    jitter (``color``) cannot change that contrast. On LM-O it did not help the detector or the outline network
    (docs/sim2real.md, thirteenth round): measure it on your own frames (``docs/sim2real_photometry.py``).
    """

    gain: tuple[float, float] = (0.9, 1.8)
    p: float = 0.5

    def __call__(self, sample: dict[str, Any], rng: np.random.Generator) -> dict[str, Any]:
        masks = np.asarray(sample["masks"])
        if rng.random() >= self.p or not len(masks):
            return sample
        gains = rng.uniform(*self.gain, size=len(masks)).astype(np.float32)
        x = np.asarray(sample["rgb"], np.float32)
        factor = np.ones(x.shape[:2], np.float32)
        for m, g in zip(masks, gains):
            factor[np.asarray(m, bool)] = g
        return dict(sample, rgb=np.clip(np.round(x * factor[..., None]), 0, 255).astype(np.uint8))


def _texture(rng: np.random.Generator, shape: tuple[int, int], tile_px: float, seeds: int) -> np.ndarray:
    """(H, W, 3) uint8: a random procedural material's colour map (:mod:`simtest.materials.procedural`) tiled
    at ``tile_px`` pixels a tile, shifted by a random phase."""
    from simtest.materials.procedural import FAMILIES, procedural_material

    fam = FAMILIES[int(rng.integers(len(FAMILIES)))]
    albedo = procedural_material(fam, int(rng.integers(seeds)), 128).albedo
    side = max(8, int(round(tile_px)))
    tile = cv2.resize(albedo, (side, side), interpolation=cv2.INTER_AREA if side < 128 else cv2.INTER_LINEAR)
    H, W = shape
    reps = (H // side + 2, W // side + 2, 1)
    dy, dx = (int(v) for v in rng.integers(0, side, size=2))
    return np.ascontiguousarray(np.tile(tile, reps)[dy:dy + H, dx:dx + W])


@dataclass(frozen=True)
class BackgroundSwap:
    """Replace everything but the annotated objects' visible pixels by a random cluttered background (with
    probability ``p``): a tiled procedural material (:mod:`simtest.materials.procedural`) under 4 to
    ``max_patches`` random polygons of other materials or flat colours, with a brightness ramp. Like the
    cut-and-paste training of real-data methods, it shows the networks many backgrounds; the rendered scene is
    kept for the other ``1 - p`` of samples.

    Only RGB changes: depth is left as rendered (the swap is for RGB-only networks) and the visible masks stay
    exact, since every object pixel is kept. Distractors and the room are replaced too.
    """

    p: float = 0.5
    max_patches: int = 14
    seeds: int = 12  # variants per material family: 108 in all, within the materials' cache

    def __call__(self, sample: dict[str, Any], rng: np.random.Generator) -> dict[str, Any]:
        masks = np.asarray(sample["masks"])
        if rng.random() >= self.p or not len(masks):
            return sample
        rgb = np.asarray(sample["rgb"])
        H, W = rgb.shape[:2]
        bg = _texture(rng, (H, W), rng.uniform(0.1, 0.6) * max(H, W), self.seeds)
        for _ in range(int(rng.integers(4, self.max_patches + 1))):
            c = rng.uniform((0, 0), (W, H))
            r = rng.uniform(0.03, 0.25) * max(H, W)
            k = int(rng.integers(3, 9))
            ang = np.sort(rng.uniform(0, 2 * np.pi, k))
            poly = np.stack([c[0] + r * rng.uniform(0.5, 1.0, k) * np.cos(ang),
                             c[1] + r * rng.uniform(0.5, 1.0, k) * np.sin(ang)], 1)
            x0, y0 = np.clip(np.floor(poly.min(0)).astype(int), 0, (W - 1, H - 1))
            x1, y1 = np.clip(np.ceil(poly.max(0)).astype(int) + 1, 1, (W, H))
            if x1 <= x0 or y1 <= y0:
                continue
            region = np.zeros((y1 - y0, x1 - x0), np.uint8)
            cv2.fillPoly(region, [np.round(poly - (x0, y0)).astype(np.int32)], 1)
            shape = region.shape
            fill = (_texture(rng, shape, rng.uniform(0.05, 0.3) * max(H, W), self.seeds) if rng.random() < 0.6
                    else np.broadcast_to(rng.integers(0, 256, 3).astype(np.uint8), shape + (3,)))
            view = bg[y0:y1, x0:x1]
            view[region.astype(bool)] = fill[region.astype(bool)]
        across = rng.random() < 0.5  # a left-right ramp, else top-bottom
        ramp = np.linspace(rng.uniform(0.5, 1.2), rng.uniform(0.5, 1.2), W if across else H, dtype=np.float32)
        ramp = ramp[None, :, None] if across else ramp[:, None, None]
        bg = np.clip(bg.astype(np.float32) * ramp, 0, 255).astype(np.uint8)
        fg = masks.any(0)
        return dict(sample, rgb=np.where(fg[..., None], rgb, bg))


@dataclass(frozen=True)
class Compose:
    """Apply transforms in order; each gets its own child generator (adding one does not shift the others)."""

    transforms: tuple[Callable[[dict[str, Any], np.random.Generator], dict[str, Any]], ...] = field(default=())

    def __call__(self, sample: dict[str, Any], rng: np.random.Generator) -> dict[str, Any]:
        for tf, child in zip(self.transforms, rng.spawn(len(self.transforms))):
            sample = tf(sample, child)
        return sample


def augmentation(names: Sequence[str] | str | None, p: float = 0.8) -> Compose | None:
    """The training augmentation for ``names`` (subset of :data:`AUGMENTATIONS`), or None for none.

    ``occlusion``: paste occluders at level L1..L3; ``weather``: one of :data:`TRAIN_WEATHER` at severity
    1..5; ``depth``: a depth-noise preset. Each named kind is applied to a sample with probability 0.5, and a
    sample is corrupted at all with probability ``p``. ``background``: :class:`BackgroundSwap`,
    ``object-light``: :class:`ObjectLight` and ``color``: :class:`ColorJitter` (their own probabilities), in that
    order, before the corruptions.

    Raises:
        ConfigError: An unknown name (lists the valid ones).
    """
    if names is None:
        return None
    if isinstance(names, str):
        names = [n.strip() for n in names.split(",") if n.strip()]
    names = [n for n in names if n != "none"]
    bad = [n for n in names if n not in AUGMENTATIONS]
    if bad:
        raise ConfigError(f"unknown augmentation {bad[0]!r}; valid: {', '.join(AUGMENTATIONS)} (comma-separated) "
                          "or none")
    if not names:
        return None
    from simtest.corrupt import DEPTH_PRESETS

    corrupt = RandomCorrupt(weather=TRAIN_WEATHER if "weather" in names else (),
                            occlusion_levels=(1, 2, 3) if "occlusion" in names else (),
                            depth_noise=tuple(DEPTH_PRESETS) if "depth" in names else (), p=p)
    # background and colour first, in Compose slots of their own: without them the corruptions draw as before
    first = (((BackgroundSwap(),) if "background" in names else ()) + ((ObjectLight(),) if "object-light" in names else ())
             + ((ColorJitter(),) if "color" in names else ()))
    return Compose(first + (corrupt,))

