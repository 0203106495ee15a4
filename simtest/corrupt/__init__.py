"""Corruptions: ImageNet-C image corruptions, depth-sensor noise and 2D paste occlusion.

Every function is pure and takes the caller's ``numpy.random.Generator``; ground truth is never changed
(except that a paste occlusion is reflected in visible masks when a dataset copy is written, see
:func:`corrupt_dataset`). :class:`CorruptionSpec` composes the three kinds into one on-the-fly transform.
"""

from __future__ import annotations

from simtest.corrupt.dataset import corrupt_dataset, depth_m_to_png, depth_png_to_m
from simtest.corrupt.depth_presets import DEPTH_PRESETS, DepthPreset, apply_depth_noise
from simtest.corrupt.occlusion import (
    OCCLUSION_BANDS,
    OCCLUSION_DEFINITIONS,
    OcclusionInfo,
    parse_occlusion_level,
    paste_occluders,
    update_visible_masks,
    visibility_stats,
)
from simtest.corrupt.preview import preview_grid
from simtest.corrupt.spec import OCCLUSION_KINDS, CorruptionSpec
from simtest.corrupt.weather import CORRUPTIONS, SEVERITIES, WEATHER, corrupt_rgb

__all__ = [
    "CORRUPTIONS",
    "WEATHER",
    "SEVERITIES",
    "corrupt_rgb",
    "DEPTH_PRESETS",
    "DepthPreset",
    "apply_depth_noise",
    "OCCLUSION_BANDS",
    "OCCLUSION_DEFINITIONS",
    "OCCLUSION_KINDS",
    "OcclusionInfo",
    "parse_occlusion_level",
    "paste_occluders",
    "update_visible_masks",
    "visibility_stats",
    "CorruptionSpec",
    "corrupt_dataset",
    "depth_png_to_m",
    "depth_m_to_png",
    "preview_grid",
]
