"""2D paste occlusion: requested FG/BG bands, placement rules, visible-mask update."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from simtest.corrupt import (
    OCCLUSION_BANDS,
    paste_occluders,
    parse_occlusion_level,
    update_visible_masks,
    visibility_stats,
)
from simtest.errors import ConfigError


def object_scene(h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(0)
    rgb = cv2.GaussianBlur(rng.integers(0, 255, (h, w, 3), dtype=np.uint8), (5, 5), 0)
    mask = np.zeros((h, w), np.uint8)
    cv2.ellipse(mask, (w // 2, h // 2), (w // 6, h // 4), 20, 0, 360, 1, -1)
    return rgb, mask.astype(bool)


@pytest.mark.parametrize("shape", [(48, 64), (120, 160)])
@pytest.mark.parametrize("level", ["L1", "L2", "L3"])
def test_pascal3d_bands(shape: tuple[int, int], level: str) -> None:
    rgb, obj = object_scene(*shape)
    fg_band, bg_band, _ = OCCLUSION_BANDS["pascal3d+"][int(level[1])]
    for seed in range(4):
        out, occ, info = paste_occluders(rgb, obj, level, np.random.default_rng(seed))
        fg = (occ & obj).sum() / obj.sum()
        bg = (occ & ~obj).sum() / (~obj).sum()
        assert info.fg_fraction == pytest.approx(fg) and info.bg_fraction == pytest.approx(bg)
        assert fg_band[0] <= fg <= fg_band[1], (seed, fg)
        assert bg_band[0] <= bg <= bg_band[1], (seed, bg)
        assert info.in_band and info.definition == "pascal3d+" and 1 <= info.n_occluders <= 3
        assert info.trials <= 40
        # only occluder pixels change; depth is not an input at all
        np.testing.assert_array_equal(out[~occ], rgb[~occ])
        assert out.dtype == np.uint8 and out.shape == rgb.shape


@pytest.mark.parametrize("level", [1, 2, 3])
def test_objectcentric_fg(level: int) -> None:
    rgb, obj = object_scene(96, 128)
    fg_band, _, (fg_t, _) = OCCLUSION_BANDS["objectcentric"][level]
    fgs = [paste_occluders(rgb, obj, level, np.random.default_rng(s), definition="objectcentric")[2].fg_fraction
           for s in range(5)]
    assert fg_band[0] <= np.median(fgs) <= fg_band[1]
    assert abs(np.mean(fgs) - fg_t) < 0.1


def test_deterministic_level0_and_bank() -> None:
    rgb, obj = object_scene(48, 64)
    a = paste_occluders(rgb, obj, 2, np.random.default_rng(5))
    b = paste_occluders(rgb, obj, 2, np.random.default_rng(5))
    np.testing.assert_array_equal(a[0], b[0])
    np.testing.assert_array_equal(a[1], b[1])
    out, occ, info = paste_occluders(rgb, obj, "L0", np.random.default_rng(0))
    np.testing.assert_array_equal(out, rgb)
    assert not occ.any() and info.level == 0
    patch = np.zeros((20, 30, 4), np.uint8)
    patch[..., :3] = (10, 200, 10)
    cv2.circle(patch, (15, 10), 9, (10, 200, 10, 255), -1)
    out, occ, info = paste_occluders(rgb, obj, 1, np.random.default_rng(0), occluder_bank=[patch])
    assert set(info.kinds) == {"bank"} and occ.any()
    assert np.all(out[occ] == (10, 200, 10))


def test_first_occluder_on_object_and_border_margin() -> None:
    rgb, obj = object_scene(240, 320)
    for h, w, margin in ((240, 320, 24), (480, 640, 25), (48, 64, 4)):
        rgb, obj = object_scene(h, w)
        for seed in range(3):
            _, occ, info = paste_occluders(rgb, obj, 1 + seed, np.random.default_rng(seed))
            assert info.margin == margin and 1 <= len(info.centers) <= 3
            x0, y0 = info.centers[0]
            assert obj[int(y0), int(x0)]
            for x, y in info.centers:
                assert margin <= x <= w - 1 - margin and margin <= y <= h - 1 - margin


def test_empty_object_mask() -> None:
    rgb, obj = object_scene(48, 64)
    out, occ, info = paste_occluders(rgb, np.zeros_like(obj), 2, np.random.default_rng(0))
    assert info.fg_fraction == 0.0 and info.object_pixels == 0
    assert info.bg_band[0] <= info.bg_fraction <= info.bg_band[1]


def test_update_visible_masks_and_stats() -> None:
    m1 = np.zeros((10, 12), bool)
    m1[2:6, 3:9] = True
    m2 = np.zeros((10, 12), bool)
    m2[5:9, 0:4] = True
    occ = np.zeros((10, 12), bool)
    occ[:, 6:] = True
    n1, n2 = update_visible_masks([m1, m2], occ)
    np.testing.assert_array_equal(n1, m1 & ~occ)
    np.testing.assert_array_equal(n2, m2)
    assert len(update_visible_masks(m1, occ)) == 1
    st = visibility_stats(n1, px_count_all=30)
    assert st == {"px_count_visib": 12, "visib_fract": 0.4, "bbox_visib": [3, 2, 2, 3]}  # BOP: w = xmax - xmin
    assert visibility_stats(np.zeros((4, 4), bool), 0) == {"px_count_visib": 0, "visib_fract": 0.0,
                                                          "bbox_visib": [-1, -1, -1, -1]}


def test_errors() -> None:
    rgb, obj = object_scene(48, 64)
    for bad in ("L4", 5, "x", -1, True):
        with pytest.raises(ConfigError, match="L1"):
            parse_occlusion_level(bad)
    with pytest.raises(ConfigError, match="objectcentric"):
        paste_occluders(rgb, obj, 1, np.random.default_rng(0), definition="imagenet")
    with pytest.raises(ConfigError, match="shape"):
        paste_occluders(rgb, obj[:10], 1, np.random.default_rng(0))
    assert parse_occlusion_level("l2") == 2 and parse_occlusion_level(3) == 3
