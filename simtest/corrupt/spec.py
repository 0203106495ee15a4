"""A composite corruption (image corruption + paste occlusion + depth noise) usable as an on-the-fly transform."""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from simtest.corrupt.depth_presets import DEPTH_PRESETS, apply_depth_noise, check_depth_preset
from simtest.corrupt.occlusion import OCCLUSION_BANDS, parse_occlusion_level, paste_occluders
from simtest.corrupt.weather import check_corruption_name, check_severity, corrupt_rgb
from simtest.errors import ConfigError

__all__ = ["CorruptionSpec", "OCCLUSION_KINDS", "union_mask"]

#: Occlusion kinds a 2D transform can apply. Physical occluders (objects placed between camera and target)
#: are a scene-generation option, measured from the renderer, not a post-hoc corruption.
OCCLUSION_KINDS: tuple[str, ...] = ("paste", "objects")


def union_mask(masks: np.ndarray | Sequence[np.ndarray] | None, shape: tuple[int, int]) -> np.ndarray:
    """Union of one ``(H, W)`` mask, an ``(N, H, W)`` stack or a sequence of masks, as ``(H, W)`` bool."""
    out = np.zeros(shape, bool)
    if masks is None:
        return out
    items = [masks] if isinstance(masks, np.ndarray) and masks.ndim == 2 else list(masks)
    for m in items:
        m = np.asarray(m)
        if m.shape != shape:
            raise ConfigError(f"mask shape {m.shape} does not match the image {shape}")
        out |= m.astype(bool)
    return out


@dataclass(frozen=True)
class CorruptionSpec:
    """What to corrupt and how much; ground truth is never changed by :meth:`apply`.

    Attributes:
        weather: An image corruption name from :data:`simtest.corrupt.CORRUPTIONS` (any of the 19, not only
            the four weather ones), or None.
        severity: 1..5 for ``weather``.
        depth_noise: A preset name from :data:`simtest.corrupt.DEPTH_PRESETS`, or None.
        occlusion: Occlusion level 1..3 (``"L1".."L3"`` accepted and stored as an int), or None (0 -> None).
        occlusion_kind: ``"objects"`` (default: 2D cutouts of rendered objects, :mod:`simtest.corrupt.cutouts`,
            passed to :meth:`apply` as ``occluder_bank``; without one, noise shapes are pasted instead, with a
            ``UserWarning``) or ``"paste"`` (2D noise/crop-textured ellipses and polygons). Depth is untouched.
        occlusion_definition: ``"pascal3d+"`` or ``"objectcentric"`` level bands.
    """

    weather: str | None = None
    severity: int = 4
    depth_noise: str | None = None
    occlusion: int | None = None
    occlusion_kind: str = "objects"
    occlusion_definition: str = "pascal3d+"

    def __post_init__(self) -> None:
        if self.weather is not None:
            check_corruption_name(self.weather)
        object.__setattr__(self, "severity", check_severity(self.severity))
        if self.depth_noise is not None:
            check_depth_preset(self.depth_noise)
        if self.occlusion is not None:
            level = parse_occlusion_level(self.occlusion)
            object.__setattr__(self, "occlusion", level or None)
        if self.occlusion_kind not in OCCLUSION_KINDS:
            raise ConfigError(f"unknown occlusion kind {self.occlusion_kind!r}; valid kinds: "
                              f"{', '.join(OCCLUSION_KINDS)} (physical occluders are placed at generation time)")
        if self.occlusion_definition not in OCCLUSION_BANDS:
            raise ConfigError(f"unknown occlusion definition {self.occlusion_definition!r}; valid: "
                              f"{', '.join(OCCLUSION_BANDS)}")

    @property
    def is_identity(self) -> bool:
        """True when nothing is corrupted."""
        return self.weather is None and self.depth_noise is None and self.occlusion is None

    def label(self) -> str:
        """Short name, e.g. ``"fog-4+occL2-paste+azure-kinect"`` (``"clean"`` for the identity)."""
        parts = []
        if self.weather is not None:
            parts.append(f"{self.weather}-{self.severity}")
        if self.occlusion is not None:
            parts.append(f"occL{self.occlusion}-{self.occlusion_kind}")
        if self.depth_noise is not None:
            parts.append(self.depth_noise)
        return "+".join(parts) or "clean"

    def to_dict(self) -> dict[str, Any]:
        return {"weather": self.weather, "severity": self.severity, "depth_noise": self.depth_noise,
                "occlusion": self.occlusion, "occlusion_kind": self.occlusion_kind,
                "occlusion_definition": self.occlusion_definition}

    @staticmethod
    def from_dict(d: Mapping[str, Any]) -> "CorruptionSpec":
        known = set(CorruptionSpec.__dataclass_fields__)
        unknown = set(d) - known
        if unknown:
            raise ConfigError(f"unknown corruption spec fields {sorted(unknown)}; valid fields: {sorted(known)}")
        return CorruptionSpec(**dict(d))

    def apply(self, rgb: np.ndarray, depth: np.ndarray | None, masks: np.ndarray | Sequence[np.ndarray] | None,
              rng: np.random.Generator, K: np.ndarray | None, occluder_bank: Sequence[np.ndarray] | None = None
              ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray]:
        """Corrupt one observation.

        Order: paste occlusion on the clean image, then the image corruption (so fog or frost also covers the
        occluders), then depth noise (dark/specular dropout looks at the clean image: it models the real
        surface, not the paste). Each stage draws from its own child of ``rng`` (``rng.spawn(3)``), so e.g.
        adding depth noise does not change the corrupted image.

        Args:
            rgb: ``(H, W, 3)`` uint8.
            depth: ``(H, W)`` planar depth in metres (0 = missing), or None when only the image is needed.
            masks: Object mask(s) whose occlusion the level controls (their union is used); required when
                ``occlusion`` is set. Typically the visible masks of the annotated objects.
            rng: Source of all randomness.
            K: 3x3 intrinsics (pixels); required by the Kinect-v1 and D435 depth presets.
            occluder_bank: RGBA patches pasted by the ``objects`` occlusion kind; without them that kind pastes
                noise shapes (as ``"paste"``) and warns once (``UserWarning``).

        Returns:
            ``(rgb, depth, occluder_mask)``: new arrays (``depth`` is returned as given, as float32, when no
            depth noise is asked, or None if it was None); ``occluder_mask`` is ``(H, W)`` bool, all False
            without occlusion. Update visible masks with :func:`simtest.corrupt.update_visible_masks`.
        """
        out_rgb, out_depth, occ, _ = self.apply_with_info(rgb, depth, masks, rng, K, occluder_bank)
        return out_rgb, out_depth, occ

    def apply_with_info(self, rgb: np.ndarray, depth: np.ndarray | None,
                        masks: np.ndarray | Sequence[np.ndarray] | None, rng: np.random.Generator,
                        K: np.ndarray | None, occluder_bank: Sequence[np.ndarray] | None = None
                        ) -> tuple[np.ndarray, np.ndarray | None, np.ndarray, dict[str, Any] | None]:
        """As :meth:`apply`, plus the occlusion info dict (achieved FG/BG fractions) or None."""
        rgb = np.asarray(rgb)
        if rgb.dtype != np.uint8 or rgb.ndim != 3 or rgb.shape[2] != 3:
            raise ConfigError(f"rgb must be an (H, W, 3) uint8 array, got {rgb.dtype} {rgb.shape}")
        h, w = rgb.shape[:2]
        occ_rng, rgb_rng, depth_rng = rng.spawn(3)
        out = rgb.copy()
        occ = np.zeros((h, w), bool)
        info = None
        if self.occlusion is not None:
            if masks is None:
                raise ConfigError("occlusion needs the object masks (masks=None was given)")
            obj = union_mask(masks, (h, w))
            bank = None
            if self.occlusion_kind == "objects":
                if occluder_bank:
                    bank = occluder_bank
                else:
                    warnings.warn("the 'objects' occlusion kind got no object cutouts (occluder_bank, see "
                                  "simtest.corrupt.cutouts.object_cutouts): pasting noise shapes instead; pass "
                                  "occlusion_kind='paste' to choose them", UserWarning, stacklevel=3)
            out, occ, occ_info = paste_occluders(out, obj, self.occlusion, occ_rng, occluder_bank=bank,
                                                 definition=self.occlusion_definition)
            info = occ_info.to_dict()
        if self.weather is not None:
            out = corrupt_rgb(out, self.weather, self.severity, rgb_rng)
        out_depth = None if depth is None else np.asarray(depth, dtype=np.float32)
        if self.depth_noise is not None:
            if out_depth is None:
                raise ConfigError(f"depth noise {self.depth_noise!r} needs a depth image (depth=None was given)")
            if out_depth.shape != (h, w):
                raise ConfigError(f"depth shape {out_depth.shape} does not match the image {(h, w)}")
            out_depth = apply_depth_noise(out_depth, self.depth_noise, depth_rng, K, rgb=rgb)
        return out, out_depth, occ, info

    def describe(self) -> dict[str, Any]:
        """The spec plus the parameters it implies (depth preset chain, occlusion bands), for provenance."""
        d: dict[str, Any] = {"spec": self.to_dict(), "label": self.label()}
        if self.depth_noise is not None:
            d["depth_noise"] = DEPTH_PRESETS[self.depth_noise].to_dict()
        if self.occlusion is not None:
            fg, bg, target = OCCLUSION_BANDS[self.occlusion_definition][self.occlusion]
            d["occlusion"] = {"definition": self.occlusion_definition, "level": self.occlusion,
                              "fg_band": list(fg), "bg_band": list(bg), "target": list(target)}
        return d
