"""The procedural material families: shapes, determinism, looks within each family, seamless tiling."""

from __future__ import annotations

import hashlib
import subprocess
import sys

import numpy as np
import pytest

from simtest.errors import ConfigError
from simtest.materials import FAMILIES, MaterialMaps, decode_normal, height_to_normal, procedural_material

#: Minimum standard deviation of the albedo's luminance (sRGB levels) per family: no material is a flat colour.
SPREAD_FLOOR = {"wood": 5.0, "tiles": 8.0, "fabric": 3.0, "concrete": 2.0, "marble": 5.0, "brushed_metal": 1.5,
                "painted_plastic": 0.4, "cardboard": 1.5, "paper": 1.0}
#: Typical (median) roughness range of each family, in [0, 1].
ROUGHNESS = {"wood": (0.3, 0.6), "tiles": (0.0, 0.3), "fabric": (0.8, 1.0), "concrete": (0.8, 1.0),
             "marble": (0.0, 0.2), "brushed_metal": (0.2, 0.45), "painted_plastic": (0.3, 0.6),
             "cardboard": (0.8, 1.0), "paper": (0.8, 1.0)}


def _lum(a: np.ndarray) -> np.ndarray:
    a = a.astype(np.float64)
    return a.mean(axis=-1) if a.ndim == 3 else a


def _seam_ratio(a: np.ndarray) -> float:
    """Largest ratio (over both axes) of the wrap-around seam's mean difference to the largest interior
    neighbour-line difference (with half a level of slack for quantisation)."""
    worst = 0.0
    for b in (_lum(a), _lum(a).T):
        interior = np.abs(np.diff(b, axis=1)).mean(axis=0)
        seam = np.abs(b[:, 0] - b[:, -1]).mean()
        worst = max(worst, seam / (interior.max() + 0.5))
    return worst


@pytest.mark.parametrize("size", [64, 256])
@pytest.mark.parametrize("family", FAMILIES)
def test_family_maps(family, size):
    m = procedural_material(family, 3, size)
    assert isinstance(m, MaterialMaps) and m.name == family
    assert m.albedo.shape == (size, size, 3) and m.albedo.dtype == np.uint8
    assert m.roughness.shape == (size, size) and m.roughness.dtype == np.uint8
    assert m.normal.shape == (size, size, 3) and m.normal.dtype == np.uint8
    for a in (m.albedo, m.roughness, m.normal):
        assert not a.flags.writeable
        with pytest.raises(ValueError):
            a[0, 0] = 0
    assert 0.0 <= m.metallic <= 1.0 and 0.0 <= m.specular <= 1.0 and m.tile_m > 0
    assert _lum(m.albedo).std() > SPREAD_FLOOR[family]
    lo, hi = ROUGHNESS[family]
    assert lo <= np.median(m.roughness) / 255.0 <= hi
    n = decode_normal(m.normal)
    raw = (m.normal.astype(np.float64) - 128.0) / 127.0
    assert np.allclose(np.linalg.norm(raw, axis=-1), 1.0, atol=0.03)
    assert (n[..., 2] > 0).all()
    for a in (m.albedo, m.roughness, m.normal):
        assert _seam_ratio(a) <= 1.25


def _digest(m: MaterialMaps) -> str:
    return hashlib.sha256(m.albedo.tobytes() + m.roughness.tobytes() + m.normal.tobytes()).hexdigest()


def test_same_seed_same_bytes_in_a_fresh_process():
    code = ("import hashlib; from simtest.materials import FAMILIES, procedural_material as p\n"
            "for f in FAMILIES:\n"
            "    m = p(f, 11, 64)\n"
            "    print(hashlib.sha256(m.albedo.tobytes() + m.roughness.tobytes() + m.normal.tobytes()).hexdigest())")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.split()
    assert out == [_digest(procedural_material(f, 11, 64)) for f in FAMILIES]


@pytest.mark.parametrize("family", FAMILIES)
def test_other_seed_differs(family):
    a, c = procedural_material(family, 11, 64), procedural_material(family, 12, 64)
    assert procedural_material(family, 11, 64) is a                 # cached
    assert _digest(a) != _digest(c)
    assert np.abs(a.albedo.astype(int) - c.albedo.astype(int)).mean() > 1.0


def test_family_character():
    metal = procedural_material("brushed_metal", 0, 128)
    assert metal.metallic == 1.0
    assert all(procedural_material(f, 0, 64).metallic == 0.0 for f in FAMILIES if f != "brushed_metal")
    # brushed metal: streaks along u, so neighbours along a row differ much less than along a column
    lum = _lum(metal.albedo)
    assert np.abs(np.diff(lum, axis=1)).mean() * 3 < np.abs(np.diff(lum, axis=0)).mean()
    for seed in range(4):
        tiles = procedural_material("tiles", seed, 256)
        grout, face = tiles.roughness > 200, tiles.roughness < 80
        assert grout.mean() > 0.02 and face.mean() > 0.6
        assert _lum(tiles.albedo)[grout].mean() < _lum(tiles.albedo)[face].mean()
        flat = (tiles.normal == (128, 128, 255)).all(axis=-1)
        assert flat[face].mean() > 0.8                             # glossy tile faces are flat
    paper = procedural_material("paper", 0, 128)
    assert _lum(paper.albedo).mean() > 200


def test_height_to_normal():
    assert (height_to_normal(np.zeros((8, 8)), 5.0) == (128, 128, 255)).all()
    h = np.zeros((16, 16))
    h[:, 8:] = np.arange(8)                                        # a ramp rising to the right (+u) on the right half
    n = decode_normal(height_to_normal(h, 1.0))
    assert (height_to_normal(h, 1.0)[:, 1:6] == (128, 128, 255)).all()
    assert (n[:, 10:14, 0] < -0.5).all() and np.allclose(n[:, 10:14, 1], 0.0, atol=0.01)
    up = np.repeat(np.arange(16.0)[::-1, None], 16, axis=1)      # rises toward row 0, i.e. toward +v
    assert (decode_normal(height_to_normal(up, 1.0))[2:-2, :, 1] < -0.5).all()


@pytest.mark.parametrize("bad", ["velvet", "Wood", ""])
def test_unknown_family(bad):
    with pytest.raises(ConfigError, match=repr(bad)) as err:
        procedural_material(bad, 0, 64)
    assert "painted_plastic" in str(err.value)


@pytest.mark.parametrize("size", [16, 100, 4096, 0, 48])
def test_bad_size(size):
    with pytest.raises(ConfigError, match=str(size)):
        procedural_material("wood", 0, size)
