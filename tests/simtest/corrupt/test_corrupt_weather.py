"""ImageNet-C image corruptions: determinism, shapes, severity trends, errors, speed."""

from __future__ import annotations


import cv2
import numpy as np
import pytest

from simtest.corrupt import CORRUPTIONS, WEATHER, corrupt_rgb
from simtest.errors import ConfigError

NAMES = list(CORRUPTIONS)
#: Corruptions that draw no random numbers.
DETERMINISTIC = {"defocus_blur", "zoom_blur", "gaussian_blur", "brightness", "contrast", "saturate", "pixelate",
                 "jpeg_compression"}


def make_image(h: int, w: int, seed: int = 0) -> np.ndarray:
    """A smooth colour image with two shapes and some fine texture (uint8 RGB)."""
    rng = np.random.default_rng(seed)
    yy, xx = np.mgrid[0:h, 0:w].astype(np.float32)
    img = np.stack([xx / w, yy / h, 0.5 + 0.3 * np.sin(xx / 5.0) * np.cos(yy / 7.0)], -1) * 200 + 20
    img += cv2.GaussianBlur(rng.normal(0, 12, (h, w, 3)).astype(np.float32), (0, 0), 1.0).reshape(h, w, 3)
    img = np.clip(img, 0, 255).astype(np.uint8)
    cv2.rectangle(img, (w // 8, h // 8), (w // 2, h // 2), (30, 180, 60), -1)
    cv2.circle(img, (2 * w // 3, 2 * h // 3), max(2, min(h, w) // 5), (200, 40, 40), -1)
    return img


IMG = make_image(48, 64)


def test_registry() -> None:
    assert len(CORRUPTIONS) == 19
    assert set(WEATHER) == {"brightness", "frost", "snow", "fog"} and set(WEATHER) <= set(CORRUPTIONS)
    assert {"saturate", "spatter", "speckle_noise", "gaussian_blur", "elastic_transform"} <= set(CORRUPTIONS)


@pytest.mark.parametrize("name", NAMES)
def test_deterministic_shape_dtype(name: str) -> None:
    for severity in (1, 5):
        a = corrupt_rgb(IMG, name, severity, np.random.default_rng(7))
        b = corrupt_rgb(IMG, name, severity, np.random.default_rng(7))
        assert a.shape == IMG.shape and a.dtype == np.uint8
        np.testing.assert_array_equal(a, b)
    if name not in DETERMINISTIC:
        c = corrupt_rgb(IMG, name, 3, np.random.default_rng(1))
        d = corrupt_rgb(IMG, name, 3, np.random.default_rng(2))
        assert not np.array_equal(c, d)
    assert not np.array_equal(corrupt_rgb(IMG, name, 5, np.random.default_rng(0)), IMG)


@pytest.mark.parametrize("name", NAMES)
@pytest.mark.parametrize("shape", [(37, 53), (1, 5), (53, 37)])
def test_odd_sizes(name: str, shape: tuple[int, int]) -> None:
    img = make_image(*shape, seed=3)
    for severity in (1, 4):
        out = corrupt_rgb(img, name, severity, np.random.default_rng(0))
        assert out.shape == img.shape and out.dtype == np.uint8


def _lap_var(x: np.ndarray) -> float:
    g = cv2.cvtColor(x, cv2.COLOR_RGB2GRAY).astype(np.float64)
    return float(cv2.Laplacian(g, cv2.CV_64F).var())


def _mse(x: np.ndarray, ref: np.ndarray = IMG) -> float:
    return float(np.mean((x.astype(np.float64) - ref) ** 2))


def _saturation(x: np.ndarray) -> float:
    f = x.astype(np.float64)
    v = f.max(axis=2)
    return float(np.mean(np.where(v > 0, (v - f.min(axis=2)) / np.maximum(v, 1), 0)))


# name -> (statistic, +1 increasing / -1 decreasing with severity)
TRENDS = {
    "gaussian_noise": (_mse, 1),
    "shot_noise": (_mse, 1),
    "impulse_noise": (_mse, 1),
    "speckle_noise": (_mse, 1),
    "defocus_blur": (_lap_var, -1),
    "glass_blur": (_lap_var, -1),
    "motion_blur": (_lap_var, -1),
    "zoom_blur": (_lap_var, -1),
    "gaussian_blur": (_lap_var, -1),
    "brightness": (lambda x: float(x.mean()), 1),
    "contrast": (lambda x: float(x.std()), -1),
    "jpeg_compression": (_mse, 1),
    "snow": (_mse, 1),
    "frost": (_mse, 1),
    "spatter": (_mse, 1),
}


@pytest.mark.parametrize("name", list(TRENDS))
def test_severity_monotone(name: str) -> None:
    stat, sign = TRENDS[name]
    img = make_image(96, 128, seed=1) if stat is _lap_var else IMG
    values = []
    for severity in range(1, 6):
        outs = [corrupt_rgb(img, name, severity, np.random.default_rng(k)) for k in range(3)]
        values.append(np.mean([stat(o) if stat is not _mse else _mse(o, img) for o in outs]))
    v = sign * np.asarray(values)
    span = v[-1] - v[0]
    assert span > 0, (name, values)
    # non-decreasing up to 2 % of the overall change (ties at tiny images)
    assert np.all(np.diff(v) >= -0.02 * span), (name, values)


def test_blur_reduces_laplacian_energy() -> None:
    img = make_image(96, 128, seed=1)
    base = _lap_var(img)
    for name in ("defocus_blur", "glass_blur", "motion_blur", "zoom_blur", "gaussian_blur"):
        assert _lap_var(corrupt_rgb(img, name, 1, np.random.default_rng(0))) < base


def test_other_trends() -> None:
    rng = np.random.default_rng
    # saturate: severities 1-2 desaturate, 3-5 saturate more and more
    s = [_saturation(corrupt_rgb(IMG, "saturate", k, rng(0))) for k in range(1, 6)]
    s0 = _saturation(IMG)
    assert s[1] < s[0] < s0 < s[2] < s[3] <= s[4]
    for name in ("fog", "pixelate", "elastic_transform"):
        assert _mse(corrupt_rgb(IMG, name, 5, rng(0))) > 0
    fog1 = np.mean([_mse(corrupt_rgb(IMG, "fog", 1, rng(k))) for k in range(3)])
    fog5 = np.mean([_mse(corrupt_rgb(IMG, "fog", 5, rng(k))) for k in range(3)])
    assert fog5 > fog1


def test_brightness_matches_hsv_round_trip() -> None:
    out = corrupt_rgb(IMG, "brightness", 3, np.random.default_rng(0))
    hsv = cv2.cvtColor(IMG.astype(np.float32) / 255, cv2.COLOR_RGB2HSV)
    hsv[..., 2] = np.clip(hsv[..., 2] + 0.3, 0, 1)
    ref = np.rint(np.clip(cv2.cvtColor(hsv, cv2.COLOR_HSV2RGB), 0, 1) * 255)
    assert np.abs(out.astype(float) - ref).max() <= 1


def test_gaussian_noise_sigma() -> None:
    grey = np.full((200, 200, 3), 128, np.uint8)
    out = corrupt_rgb(grey, "gaussian_noise", 1, np.random.default_rng(0)).astype(float) / 255
    assert abs(out.std() - 0.08) < 0.004


def test_errors_name_bad_values() -> None:
    rng = np.random.default_rng(0)
    with pytest.raises(ConfigError, match="foggy") as exc:
        corrupt_rgb(IMG, "foggy", 1, rng)
    assert "gaussian_noise" in str(exc.value) and "spatter" in str(exc.value)
    for bad in (0, 6, 2.5, "3", True):
        with pytest.raises(ConfigError, match=repr(bad).replace(".", r"\.")):
            corrupt_rgb(IMG, "fog", bad, rng)
    with pytest.raises(ConfigError, match="uint8"):
        corrupt_rgb(IMG.astype(np.float32), "fog", 1, rng)
    with pytest.raises(ConfigError, match="shape"):
        corrupt_rgb(IMG[..., 0], "fog", 1, rng)
