"""User material folders: set recognition (ambientCG, Poly Haven, plain images), map loading and errors."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np
import pytest

from simtest.errors import AssetError, ConfigError
from simtest.materials import MaterialSource, decode_normal, folder_materials, load_folder_material


def _write(path: Path, rgb_or_grey: np.ndarray) -> None:
    img = rgb_or_grey[..., ::-1] if rgb_or_grey.ndim == 3 else rgb_or_grey
    assert cv2.imwrite(str(path), np.ascontiguousarray(img))


@pytest.fixture
def folder(tmp_path: Path) -> Path:
    rng = np.random.default_rng(0)
    _write(tmp_path / "Wood049_2K_Color.png", rng.integers(0, 256, (32, 32, 3), dtype=np.uint8))
    _write(tmp_path / "Wood049_2K_Roughness.png", np.full((16, 16), 40000, np.uint16))   # 16-bit, smaller
    dx = np.empty((32, 32, 3), np.uint8)
    dx[...] = (150, 100, 230)                                      # DX: green 100 = normal tilted toward -v
    _write(tmp_path / "Wood049_2K_NormalDX.png", dx)
    _write(tmp_path / "Wood049_2K_Displacement.png", np.zeros((32, 32), np.uint8))   # a map that is not used
    _write(tmp_path / "Wood049.png", np.zeros((8, 8, 3), np.uint8))                 # the set's preview
    (tmp_path / "Wood049.usdc").write_bytes(b"usd")
    (tmp_path / "README.txt").write_text("stray")
    _write(tmp_path / "Metal_Roughness.png", np.zeros((8, 8), np.uint8))            # no colour image: ignored
    sub = tmp_path / "planks"
    sub.mkdir()
    _write(sub / "planks_diff_1k.jpg", np.full((24, 48, 3), (120, 80, 40), np.uint8))
    _write(sub / "planks_rough_1k.png", np.full((24, 48, 3), 64, np.uint8))         # grey stored as RGB
    gl = np.empty((24, 48, 3), np.uint8)
    gl[...] = (128, 160, 240)
    _write(sub / "planks_nor_gl_1k.png", gl)
    deep = sub / "deeper"
    deep.mkdir()
    _write(deep / "too_deep.png", np.zeros((8, 8, 3), np.uint8))                     # two levels down: not read
    _write(tmp_path / "photo.JPG", np.full((20, 40, 3), 200, np.uint8))
    return tmp_path


def test_names_and_grouping(folder):
    found = folder_materials(str(folder))
    assert [s.name for s in found] == ["photo", "planks", "Wood049"]
    photo, planks, wood = found
    assert photo == MaterialSource("photo", str((folder / "photo.JPG").resolve()), None, None, "gl")
    assert planks.color == str((folder / "planks" / "planks_diff_1k.jpg").resolve())
    assert planks.roughness.endswith("planks_rough_1k.png") and planks.normal.endswith("planks_nor_gl_1k.png")
    assert planks.normal_convention == "gl"
    assert Path(wood.color).name == "Wood049_2K_Color.png" and Path(wood.roughness).name == "Wood049_2K_Roughness.png"
    assert Path(wood.normal).name == "Wood049_2K_NormalDX.png" and wood.normal_convention == "dx"
    assert all(Path(p).is_absolute() for s in found for p in (s.color, s.roughness, s.normal) if p)


def test_load_ambientcg_set(folder):
    wood = next(s for s in folder_materials(str(folder)) if s.name == "Wood049")
    m = load_folder_material(wood, size=16)
    assert m.name == "Wood049" and m.albedo.shape == (16, 16, 3) and m.roughness.shape == (16, 16)
    assert (m.metallic, m.specular, m.tile_m) == (0.0, 0.5, 1.0)
    assert (m.roughness == round(40000 / 65535 * 255)).all()          # 16-bit roughness scaled to 8 bits
    n = decode_normal(m.normal)
    expect = np.array([150, 255 - 100, 230]) / 255.0 * 2.0 - 1.0      # green flipped: DX -> GL
    expect /= np.linalg.norm(expect)
    assert np.allclose(n, expect, atol=0.02) and (m.normal[..., 1] > 128).all()
    big = load_folder_material(wood, size=512)
    assert big.albedo.shape == (32, 32, 3)                          # never upscaled past the colour image
    colour = cv2.imread(wood.color)[..., ::-1]
    assert np.array_equal(big.albedo, colour) and not big.albedo.flags.writeable
    assert load_folder_material(wood, size=512) is big               # cached


def test_load_poly_haven_and_plain(folder):
    found = {s.name: s for s in folder_materials(str(folder))}
    planks = load_folder_material(found["planks"], size=32)
    assert planks.albedo.shape == (32, 32, 3) and (planks.roughness == 64).all()
    assert np.allclose(decode_normal(planks.normal)[..., 1], decode_normal(np.array([128, 160, 240]))[1],
                       atol=0.02)
    photo = load_folder_material(found["photo"], size=16)
    assert (photo.roughness == 153).all() and (photo.normal == (128, 128, 255)).all()
    assert photo.albedo.shape == (16, 16, 3)


def test_errors(tmp_path):
    with pytest.raises(ConfigError, match="nowhere"):
        folder_materials(str(tmp_path / "nowhere"))
    (tmp_path / "notes.txt").write_text("no images")
    with pytest.raises(ConfigError, match=str(tmp_path)):
        folder_materials(str(tmp_path))
    (tmp_path / "broken.png").write_bytes(b"not a png")
    (broken,) = folder_materials(str(tmp_path))
    with pytest.raises(AssetError, match="broken.png"):
        load_folder_material(broken)
    with pytest.raises(ConfigError, match="size"):
        load_folder_material(broken, size=0)
