"""Training augmentations: seeded image corruptions, paste occluders and depth noise applied to samples of
:class:`simtest.data.PoseDataset` (see :func:`augmentation`)."""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from simtest.errors import ConfigError

__all__ = ["Corrupt", "RandomCorrupt", "Compose", "augmentation", "TRAIN_WEATHER", "AUGMENTATIONS"]

#: Image corruptions used by the ``weather`` augmentation. The four evaluation conditions of the robustness
#: tables (brightness, frost, snow, fog) are deliberately left out so they stay unseen in training.
TRAIN_WEATHER: tuple[str, ...] = ("gaussian_noise", "shot_noise", "defocus_blur", "motion_blur", "contrast",
                                  "saturate", "jpeg_compression", "pixelate", "gaussian_blur", "spatter")
#: Names understood by :func:`augmentation`.
AUGMENTATIONS: tuple[str, ...] = ("occlusion", "weather", "depth")


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
    sample is corrupted at all with probability ``p``.

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

    return Compose((RandomCorrupt(
        weather=TRAIN_WEATHER if "weather" in names else (),
        occlusion_levels=(1, 2, 3) if "occlusion" in names else (),
        depth_noise=tuple(DEPTH_PRESETS) if "depth" in names else (), p=p),))

