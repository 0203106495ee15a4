"""Depth-sensor noise: statistics match the published formulas, missing depth stays missing."""

from __future__ import annotations

import numpy as np
import pytest

from simtest.corrupt import DEPTH_PRESETS, apply_depth_noise
from simtest.corrupt.depth import (
    azure_axial_noise,
    azure_sigma,
    dark_dropout,
    discontinuity_dropout,
    disparity_quantization,
    incidence_angle,
    kinect_axial_noise,
    kinect_axial_sigma,
    kinect_lateral_sigma,
    quantize_depth,
    random_holes,
    stereo_axial_noise,
    stereo_sigma,
    structured_light_edge_filter,
)
from simtest.errors import ConfigError

H, W = 240, 320
K = np.array([[300.0, 0.0, (W - 1) / 2], [0.0, 300.0, (H - 1) / 2], [0.0, 0.0, 1.0]])


def plane(z: float, h: int = H, w: int = W) -> np.ndarray:
    return np.full((h, w), z, np.float32)


def tilted_plane(z0: float, deg: float, k: np.ndarray = K, h: int = H, w: int = W) -> np.ndarray:
    """Planar depth of a plane through (0, 0, z0) tilted by ``deg`` about the camera x axis."""
    v = (np.arange(h) - k[1, 2]) / k[1, 1]
    with np.errstate(divide="ignore"):
        z = z0 / (1.0 - v * np.tan(np.deg2rad(deg)))
    z[(z <= 0) | (z > 4.0)] = 0  # beyond the horizon / far away: no measurement
    return np.broadcast_to(z[:, None], (h, w)).astype(np.float32).copy()


def scene() -> tuple[np.ndarray, np.ndarray]:
    """A table plane with a box in front, a hole, and a dark stripe in the image."""
    d = plane(1.2)
    d[60:160, 100:220] = 0.8
    d[:10, :10] = 0
    d[200:205, 50:60] = 0
    rgb = np.full((H, W, 3), 128, np.uint8)
    rgb[220:] = 4
    return d, rgb


@pytest.mark.parametrize("z", [1.0, 2.0])
def test_kinect_axial_std_matches_nguyen(z: float) -> None:
    expected = 0.0012 + 0.0019 * (z - 0.4) ** 2
    assert kinect_axial_sigma(z) == pytest.approx(expected)
    d = plane(z)
    for out in (kinect_axial_noise(d, np.random.default_rng(0), K=K),
                apply_depth_noise(d, "kinect-v1", np.random.default_rng(0), K)):
        valid = out > 0
        assert valid.mean() > 0.98
        assert abs((out - d)[valid].std() / expected - 1) < 0.10
        assert abs((out - d)[valid].mean()) < 0.1 * expected


def test_kinect_angle_term() -> None:
    assert kinect_lateral_sigma(0.0) == pytest.approx(0.8)
    t = np.deg2rad(70.0)
    assert kinect_lateral_sigma(t) == pytest.approx(0.8 + 0.035 * t / (np.pi / 2 - t))
    z = 1.5
    base = 0.0012 + 0.0019 * (z - 0.4) ** 2
    assert kinect_axial_sigma(z, np.deg2rad(50.0)) == pytest.approx(base)
    assert kinect_axial_sigma(z, t) == pytest.approx(base + 0.0001 * t ** 2 / (np.sqrt(z) * (np.pi / 2 - t) ** 2))
    # on a plane tilted by 70 deg the residual normalised by the per-pixel formula has unit std
    d = tilted_plane(1.0, 70.0)
    theta = incidence_angle(d, K)
    assert abs(np.rad2deg(theta[H // 2, W // 2]) - 70.0) < 1.0
    out = kinect_axial_noise(d, np.random.default_rng(1), K=K)
    inner = (d > 0) & (theta > 0)
    r = ((out - d) / kinect_axial_sigma(d, theta))[inner]
    assert inner.sum() > 0.3 * d.size
    assert abs(r.std() - 1) < 0.1


def test_incidence_angle_fronto_parallel_and_slanted() -> None:
    theta = incidence_angle(plane(1.0), K)
    # fronto-parallel: the angle equals the angle of the viewing ray to the optical axis
    u = np.arange(W) - K[0, 2]
    expected = np.arctan(np.abs(u) / K[0, 0])
    np.testing.assert_allclose(theta[H // 2], expected, atol=2e-3)
    th60 = incidence_angle(tilted_plane(1.0, 60.0), K)
    assert abs(np.rad2deg(th60[H // 2, W // 2]) - 60.0) < 1.0


@pytest.mark.parametrize("z", [1.0, 2.0])
def test_azure_sigma(z: float) -> None:
    expected = 0.0005 + max(z - 0.5, 0) * 0.001
    assert azure_sigma(z) == pytest.approx(expected)
    d = plane(z)
    for out in (azure_axial_noise(d, np.random.default_rng(0)),
                apply_depth_noise(d, "azure-kinect", np.random.default_rng(0), K)):
        assert abs((out - d).std() / expected - 1) < 0.10


def test_stereo_sigma() -> None:
    d = plane(2.0)
    out = stereo_axial_noise(d, np.random.default_rng(0), focal_px=640.0, baseline_m=0.05, sigma_disparity_px=0.08)
    expected = 4.0 * 0.08 / (640.0 * 0.05)
    assert stereo_sigma(2.0, 640.0, 0.05, 0.08) == pytest.approx(expected)
    assert abs((out - d).std() / expected - 1) < 0.10


def test_disparity_quantization_eighth_pixel() -> None:
    d = tilted_plane(1.0, 40.0)
    out = disparity_quantization(d, np.random.default_rng(0), focal_px=480.0, baseline_m=0.075, step_px=0.125)
    disp = 480.0 * 0.075 / out[out > 0].astype(np.float64)
    np.testing.assert_allclose(disp * 8, np.round(disp * 8), atol=1e-3)
    assert np.abs(out - d).max() < 0.02


@pytest.mark.parametrize("preset", list(DEPTH_PRESETS))
def test_presets_keep_missing_and_are_deterministic(preset: str) -> None:
    d, rgb = scene()
    a = apply_depth_noise(d, preset, np.random.default_rng(3), K, rgb=rgb)
    b = apply_depth_noise(d, preset, np.random.default_rng(3), K, rgb=rgb)
    np.testing.assert_array_equal(a, b)
    assert a.shape == d.shape and a.dtype == np.float32
    assert np.all(a[d == 0] == 0)
    assert np.all(a >= 0) and np.all(np.isfinite(a))
    assert (a > 0).mean() > 0.5
    valid = (a > 0) & (d > 0)
    assert np.median(np.abs(a - d)[valid]) < 0.01  # metres: noise, not garbage
    # works without rgb and on odd sizes
    odd = apply_depth_noise(d[:37, :53], preset, np.random.default_rng(0), K)
    assert odd.shape == (37, 53) and np.all(odd[:10, :10] == 0)


def test_structured_light_invalidates_depth_edges() -> None:
    d, _ = scene()
    out = structured_light_edge_filter(d, np.random.default_rng(0))
    # next to the box edge (column 100) the window test fails; far from edges it passes
    assert np.all(out[100, 97:103] == 0)
    assert np.all(out[100, 150:170] > 0) and np.all(out[200, 250:300] > 0)
    full = apply_depth_noise(d, "structured-light", np.random.default_rng(0), K)
    assert np.all(full[100, 98:102] == 0)


def test_dropouts() -> None:
    d, rgb = scene()
    out = dark_dropout(d, np.random.default_rng(0), rgb=rgb)
    assert np.all(out[220:] == 0) and np.all(out[100:200, 250:] > 0)
    np.testing.assert_array_equal(dark_dropout(d, np.random.default_rng(0)), d)  # no rgb: no-op
    step = plane(0.5)
    step[:, W // 2:] = 1.5
    out = discontinuity_dropout(step, np.random.default_rng(0), threshold_m=0.8)
    assert np.all(out[:, W // 2 - 1:W // 2 + 1] == 0) and (out > 0).mean() > 0.98
    holes = random_holes(plane(1.0), np.random.default_rng(0), holes_per_megapixel=2000.0)
    assert 0 < (holes == 0).mean() < 0.5
    q = quantize_depth(tilted_plane(1.0, 30.0), np.random.default_rng(0), step_m=0.001)
    np.testing.assert_allclose(q * 1000, np.round(q * 1000), atol=1e-3)


def test_errors() -> None:
    d, _ = scene()
    with pytest.raises(ConfigError, match="kinect-v2") as exc:
        apply_depth_noise(d, "kinect-v2", np.random.default_rng(0), K)
    for name in DEPTH_PRESETS:
        assert name in str(exc.value)
    with pytest.raises(ConfigError, match="K"):
        apply_depth_noise(d, "kinect-v1", np.random.default_rng(0), None)
    with pytest.raises(ConfigError, match="rgb"):
        apply_depth_noise(d, "azure-kinect", np.random.default_rng(0), K, rgb=np.zeros((5, 5, 3), np.uint8))
    with pytest.raises(ConfigError, match="2D"):
        apply_depth_noise(d[None], "azure-kinect", np.random.default_rng(0), K)
