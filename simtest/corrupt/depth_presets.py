"""Named depth-sensor presets (Kinect v1, structured light, Azure Kinect-like, RealSense D435-like): the
parts of :mod:`simtest.corrupt.depth` composed in order with their parameters, and :func:`apply_depth_noise`.
Depth is planar z in metres; ``0`` = no measurement, and stays so.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping

import numpy as np

from simtest.corrupt.depth import (DepthPart, azure_axial_noise, check_rgb, dark_dropout, discontinuity_dropout,
                                   disparity_quantization, edge_dropout,
                                   grazing_dropout, keep_missing,
                                   kinect_axial_noise, kinect_lateral_noise,
                                   pixel_shift, random_holes, range_limits,
                                   require_K, specular_dropout,
                                   stereo_axial_noise,
                                   structured_light_edge_filter,
                                   structured_light_noise)
from simtest.errors import ConfigError

__all__ = ["DEPTH_PRESETS", "DepthPreset", "apply_depth_noise", "check_depth_preset"]


@dataclass(frozen=True)
class DepthPreset:
    """A named chain of depth-noise parts, applied in order.

    Attributes:
        name: Registry name.
        description: One line: what sensor and which source.
        steps: ``(part, params)`` pairs; each part is called as ``part(depth, rng, K=K, rgb=rgb, **params)``.
    """

    name: str
    description: str
    steps: tuple[tuple[DepthPart, Mapping[str, Any]], ...] = field(default=())

    def __call__(self, depth: np.ndarray, rng: np.random.Generator, K: np.ndarray | None,
                 rgb: np.ndarray | None = None) -> np.ndarray:
        out = np.asarray(depth, dtype=np.float32)
        for part, params in self.steps:
            out = part(out, rng, K=K, rgb=rgb, **dict(params))
        return keep_missing(out, np.asarray(depth, dtype=np.float32))

    def to_dict(self) -> dict[str, Any]:
        """JSON-able description (part names and parameters)."""
        return {"name": self.name, "description": self.description,
                "steps": [{"part": p.__name__, **{k: (list(v) if isinstance(v, tuple) else v)
                                                  for k, v in params.items()}} for p, params in self.steps]}


_ICL_F, _ICL_B = 480.0, 0.075

#: Named sensor presets; see the module docstring for the formulas.
DEPTH_PRESETS: dict[str, DepthPreset] = {
    p.name: p
    for p in (
        DepthPreset(
            "kinect-v1",
            "Kinect v1 (Nguyen et al. 2012): lateral and axial noise from depth and incidence angle, grazing "
            "and depth-edge dropout, specular dropout, range 0.4-4.0 m",
            (
                (kinect_lateral_noise, {}),
                (kinect_axial_noise, {}),
                (grazing_dropout, {"start_deg": 70.0, "end_deg": 85.0}),
                (edge_dropout, {"threshold_m": 0.05, "width_px": 1, "probability": 0.5}),
                (specular_dropout, {}),
                (range_limits, {"z_min": 0.4, "z_max": 4.0}),
            ),
        ),
        DepthPreset(
            "structured-light",
            "Structured light (Handa et al. 2014, ICL-NUIM): 0.5 px bilinear shifts, 1/8 px disparity "
            "quantisation (f = 480 px, b = 0.075 m), 9x9 edge invalidation, 35130 / disparity noise",
            (
                (pixel_shift, {"sigma_px": 0.5, "bilinear": True}),
                (disparity_quantization, {"focal_px": _ICL_F, "baseline_m": _ICL_B, "step_px": 0.125}),
                (structured_light_edge_filter, {"focal_px": _ICL_F, "baseline_m": _ICL_B}),
                (structured_light_noise, {}),
            ),
        ),
        DepthPreset(
            "azure-kinect",
            "Azure Kinect-like: 0.25 px shifts, (0.0005 + max(z - 0.5, 0) 0.001) m Gaussian noise, dropout "
            "where the 3x3 depth range > 0.8 m and on dark pixels (grey < 15)",
            (
                (pixel_shift, {"sigma_px": 0.25, "bilinear": True}),
                (azure_axial_noise, {}),
                (discontinuity_dropout, {"threshold_m": 0.8, "window": 3}),
                (dark_dropout, {"grey_threshold": 15.0}),
            ),
        ),
        DepthPreset(
            "realsense-d435",
            "RealSense D435-like active stereo: 0.25 px shifts, z^2 sigma_d / (f b) noise (f = 640 px, "
            "b = 0.05 m, sigma_d = 0.08 px), 1/32 px disparity steps, missing data at depth edges, on dark, "
            "specular and grazing surfaces, random holes, range 0.2-10 m",
            (
                (pixel_shift, {"sigma_px": 0.25, "bilinear": True}),
                (stereo_axial_noise, {"focal_px": 640.0, "baseline_m": 0.05, "sigma_disparity_px": 0.08}),
                (disparity_quantization, {"focal_px": 640.0, "baseline_m": 0.05, "step_px": 1.0 / 32.0}),
                (edge_dropout, {"threshold_m": 0.03, "width_px": 2, "probability": 0.7}),
                (dark_dropout, {"grey_threshold": 10.0, "probability": 0.8}),
                (specular_dropout, {}),
                (grazing_dropout, {"start_deg": 75.0, "end_deg": 88.0}),
                (random_holes, {"holes_per_megapixel": 60.0, "radius_px": (1.0, 6.0)}),
                (range_limits, {"z_min": 0.2, "z_max": 10.0}),
            ),
        ),
        DepthPreset(
            "stereo-ideal",
            "Ideal stereo: only disparity quantisation to 1/8 px (f = 480 px, b = 0.075 m); no noise, no dropout",
            ((disparity_quantization, {"focal_px": _ICL_F, "baseline_m": _ICL_B, "step_px": 0.125}),),
        ),
    )
}


def check_depth_preset(preset: str) -> str:
    """Return ``preset``, or raise :class:`ConfigError` listing the valid preset names."""
    if preset not in DEPTH_PRESETS:
        raise ConfigError(f"unknown depth noise preset {preset!r}; valid presets: {', '.join(DEPTH_PRESETS)}")
    return preset


def apply_depth_noise(depth: np.ndarray, preset: str | DepthPreset, rng: np.random.Generator,
                      K: np.ndarray | None, rgb: np.ndarray | None = None) -> np.ndarray:
    """Apply a named depth-sensor noise preset.

    Args:
        depth: ``(H, W)`` planar depth, metres; 0 = missing (stays 0).
        preset: A name from :data:`DEPTH_PRESETS` or a :class:`DepthPreset`.
        rng: Source of all randomness.
        K: 3x3 intrinsics (pixels) of the depth image; needed by the incidence-angle parts.
        rgb: Optional registered clean ``(H, W, 3)`` uint8 image for dark/specular dropout.

    Returns:
        A new ``float32 (H, W)`` depth image in metres.

    Raises:
        ConfigError: Unknown preset name (the valid names are listed), a depth image that is not 2D, or an
            ``rgb``/``K`` of the wrong shape.
    """
    if not isinstance(preset, DepthPreset):
        preset = DEPTH_PRESETS[check_depth_preset(preset)]
    depth = np.asarray(depth)
    if depth.ndim != 2:
        raise ConfigError(f"depth must be a 2D (H, W) array in metres, got shape {depth.shape}")
    if K is not None:
        K = require_K(K, preset.name)
    check_rgb(rgb, depth)
    return preset(depth.astype(np.float32), rng, K, rgb)
