"""Environment maps: procedural sky and studio, irradiance scale, light summaries, rotation, HDR/EXR files."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from simtest.errors import AssetError, ConfigError
from simtest.materials import (ENVIRONMENTS, Environment, environment_files, irradiance_up, light_summary,
                               procedural_environment, read_environment, rotated)
from simtest.materials.sky import sunny_sky, unit_direction
from simtest.materials.sphere import LUMA, directions


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.arccos(np.clip(np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b), -1.0, 1.0)))


@pytest.mark.parametrize("kind", ENVIRONMENTS)
def test_shapes_determinism_and_scale(kind):
    env = procedural_environment(kind, 0, 64)
    assert isinstance(env, Environment) and env.name == kind
    assert env.radiance.shape == (64, 128, 3) and env.radiance.dtype == np.float32
    assert not env.radiance.flags.writeable and (env.radiance >= 0).all() and np.isfinite(env.radiance).all()
    assert procedural_environment(kind, 0, 64) is env
    from simtest.materials.environments import procedural_environment as again

    assert again(kind, 1, 64).radiance.tobytes() != env.radiance.tobytes()
    for seed in range(5):
        e = procedural_environment(kind, seed, 64)
        assert 0.5 * np.pi <= irradiance_up(e) <= 2.0 * np.pi
    with pytest.raises(ConfigError, match="'moon'"):
        procedural_environment("moon", 0, 64)
    with pytest.raises(ConfigError, match="63"):
        procedural_environment(kind, 0, 63)


@pytest.mark.parametrize("seed", range(6))
def test_sky_sun(seed):
    env = procedural_environment("sky", seed, 128)
    y = env.radiance @ LUMA
    sun = y > 0.1 * y.max()
    assert 1 <= sun.sum() <= 30                                     # a small disk of a few texels
    no_sun = Environment("x", np.where(sun[..., None], 0.0, env.radiance))
    share = 1.0 - irradiance_up(no_sun) / irradiance_up(env)
    assert 0.68 <= share <= 0.87
    ground = y[96:]                                                 # well below the horizon
    assert 0.18 <= ground.mean() <= 0.32
    assert y[:64][~sun[:64]].min() > 0
    ambient, lights = light_summary(env)
    phi = np.arctan2(lights[0][0][1], lights[0][0][0]) + np.pi     # away from the sun
    col = int((phi % (2 * np.pi)) / (2 * np.pi) * 256)
    assert y[62, col] > y[21, col]                                 # brighter toward the horizon (85 vs 30 deg)
    rgb = env.radiance
    assert rgb[21, col, 2] / rgb[21, col, 0] > rgb[62, col, 2] / rgb[62, col, 0] > 1.0   # bluer up high
    assert len(lights) >= 1 and ambient.shape == (3,) and (ambient > 0).all()
    direction, irradiance = lights[0]
    assert direction.shape == (3,) and irradiance.shape == (3,) and abs(np.linalg.norm(direction) - 1) < 1e-5
    for texel in directions(128)[sun]:
        assert _angle(direction, texel) <= 1.5 * np.pi / 128         # inside the small disk
    assert np.sin(np.radians(14)) <= direction[2] <= np.sin(np.radians(76))
    assert irradiance @ LUMA * direction[2] > 0.6 * irradiance_up(env)
    again = light_summary(env)
    assert np.array_equal(again[0], ambient) and np.array_equal(again[1][0][0], direction)


@pytest.mark.parametrize("elevation, azimuth", [(20.0, 10.0), (47.3, 200.0), (70.0, 333.3)])
def test_light_summary_finds_a_known_sun(elevation, azimuth):
    sun = unit_direction(np.radians(elevation), np.radians(azimuth))
    env = Environment("known", sunny_sky(128, sun, share=0.8))
    assert np.isclose(irradiance_up(env), np.pi, rtol=1e-3)
    ambient, lights = light_summary(env)
    assert _angle(lights[0][0], sun) <= np.pi / 128                # within a texel
    assert np.isclose(lights[0][1] @ LUMA * sun[2], 0.8 * np.pi, rtol=0.02)
    assert len(lights) == 1 and (ambient > 0).all()


def test_studio_lights():
    for seed in range(4):
        env = procedural_environment("studio", seed, 64)
        y = env.radiance @ LUMA
        ambient, lights = light_summary(env)
        assert 2 <= len(lights) <= 3 and (ambient > 0).all()
        assert all(d[2] > 0 and (e > 0).all() for d, e in lights)
        assert np.median(y[:32]) < 0.2 * y.max()                    # dark surround, bright boxes
        assert 0.15 <= np.median(y[40:]) <= 0.4                     # the floor bounce


def test_rotated():
    env = procedural_environment("sky", 2, 64)
    col = 2 * np.pi / 128
    turned = rotated(env, 5 * col)
    assert np.array_equal(turned.radiance, np.roll(env.radiance, 5, axis=1))
    assert np.array_equal(rotated(turned, -5 * col).radiance, env.radiance)
    (d0, _), (d1, _) = light_summary(env)[1][0], light_summary(turned)[1][0]
    assert abs(np.arctan2(d1[1], d1[0]) - np.arctan2(d0[1], d0[0]) - 5 * col) % (2 * np.pi) < 1e-3
    half = rotated(env, 0.5 * col)
    assert np.allclose(half.radiance, 0.5 * (env.radiance + np.roll(env.radiance, 1, axis=1)), rtol=1e-5)
    back = rotated(half, -0.5 * col)
    assert np.allclose(back.radiance.sum(axis=1), env.radiance.sum(axis=1), rtol=1e-4)   # energy per row kept
    assert np.array_equal(rotated(env, 2 * np.pi).radiance, env.radiance)


def test_hdr_round_trip(tmp_path: Path):
    rng = np.random.default_rng(1)
    rgb = rng.uniform(0.01, 50.0, (16, 32, 3)).astype(np.float32)
    path = tmp_path / "studio_small.hdr"
    assert cv2.imwrite(str(path), rgb[..., ::-1])
    env = read_environment(str(path), height=16)
    assert env.name == "studio_small" and env.radiance.shape == (16, 32, 3)
    assert np.allclose(env.radiance, rgb, rtol=0, atol=rgb.max(axis=-1, keepdims=True) / 64.0)  # RGBE
    smaller = read_environment(str(path), height=8)
    assert smaller.radiance.shape == (8, 16, 3)
    assert np.isclose(smaller.radiance.mean(), env.radiance.mean(), rtol=1e-3)
    assert environment_files(str(tmp_path)) == (str(path.resolve()),)


def test_exr_and_bad_values(tmp_path: Path):
    rgb = np.full((8, 16, 3), 2.5, np.float32)
    rgb[0, 0] = (-1.0, np.nan, np.inf)
    path = tmp_path / "a.exr"
    try:
        ok = cv2.imwrite(str(path), rgb[..., ::-1])
    except cv2.error as exc:
        pytest.skip(f"OpenCV's OpenEXR support is unavailable here: {exc}")
    if not ok:
        pytest.skip("OpenCV's OpenEXR writer is unavailable here")
    env = read_environment(str(path), height=8)
    assert (env.radiance[0, 0] == 0).all() and np.allclose(env.radiance[1:], 2.5)
    (tmp_path / "b.hdr").write_bytes(b"")
    (tmp_path / "c.txt").write_text("x")
    assert [Path(p).name for p in environment_files(str(tmp_path))] == ["a.exr", "b.hdr"]


def test_file_errors(tmp_path: Path):
    broken = tmp_path / "broken.exr"
    broken.write_bytes(b"not an exr")
    with pytest.raises(AssetError, match=r"broken\.exr.*\.hdr"):
        read_environment(str(broken))
    (tmp_path / "broken.hdr").write_bytes(b"not an hdr")
    with pytest.raises(AssetError, match=r"broken\.hdr"):
        read_environment(str(tmp_path / "broken.hdr"))
    square = tmp_path / "square.hdr"
    assert cv2.imwrite(str(square), np.ones((16, 16, 3), np.float32))
    with pytest.raises(AssetError, match=r"square\.hdr.*16x16"):
        read_environment(str(square))
    nearly = tmp_path / "nearly.hdr"
    assert cv2.imwrite(str(nearly), np.ones((100, 201, 3), np.float32))   # 2.01:1 is within 1 %
    assert read_environment(str(nearly), height=10).radiance.shape == (10, 20, 3)
    with pytest.raises(AssetError, match="missing.hdr"):
        read_environment(str(tmp_path / "missing.hdr"))
    with pytest.raises(ConfigError, match="nowhere"):
        environment_files(str(tmp_path / "nowhere"))
    empty = tmp_path / "empty"
    empty.mkdir()
    with pytest.raises(ConfigError, match="no .hdr"):
        environment_files(str(empty))
