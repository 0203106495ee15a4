"""``materials.textures`` (``--textures DIR``): folder materials on the table, floor, walls and distractors."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from PIL import Image

from simtest.errors import ConfigError
from simtest.generators.looks import surface_maps
from simtest.generators.pipeline import load_objects, prepare_scene


@pytest.fixture()
def texture_dir(tmp_path):
    y, x = np.mgrid[0:40, 0:60]
    Image.fromarray(np.stack([x * 4, y * 6, 0 * x + 90], -1).astype(np.uint8)).save(tmp_path / "ramp.png")
    checker = ((x[:40, :40] // 5 + y[:40, :40] // 5) % 2 * 200 + 30).astype(np.uint8)
    Image.fromarray(np.stack([checker] * 3, -1)).save(tmp_path / "Tiles01_1K_Color.png")
    Image.fromarray(np.full((40, 40), 90, np.uint8)).save(tmp_path / "Tiles01_1K_Roughness.png")
    Image.fromarray(np.full((40, 40, 3), (128, 128, 255), np.uint8)).save(tmp_path / "Tiles01_1K_NormalGL.png")
    (tmp_path / "readme.txt").write_text("not an image")
    return tmp_path


def _texture_pixels(model: mujoco.MjModel, material: str, role=mujoco.mjtTextureRole.mjTEXROLE_RGB) -> np.ndarray:
    mat = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_MATERIAL, material)
    tex = int(model.mat_texid[mat, int(role)])
    assert tex >= 0, (material, role)
    w, h, c, adr = (int(model.tex_width[tex]), int(model.tex_height[tex]), int(model.tex_nchannel[tex]),
                    int(model.tex_adr[tex]))
    return model.tex_data[adr:adr + w * h * c].reshape(h, w, c).squeeze()


def test_texture_folder_materials_cover_the_room_and_distractors(small_config, texture_dir):
    cfg = small_config.replace(**{"materials.textures": str(texture_dir), "scene.distractors": [2, 2],
                                  "camera.width": 64, "camera.height": 48})
    scene, *_ = prepare_scene(cfg, load_objects(cfg), 0)
    spec = scene.spec
    used = {spec.table.material, spec.floor.material, spec.walls.material, *(d.material for d in spec.distractors)}
    assert used <= {"folder:Tiles01", "folder:ramp"} and None not in used
    for name, surface in (("table", spec.table), ("floor", spec.floor), ("wall", spec.walls)):
        np.testing.assert_array_equal(_texture_pixels(scene.model, f"{name}_mat"),
                                      surface_maps(cfg, surface.material).albedo)
    for j, d in enumerate(spec.distractors):
        np.testing.assert_array_equal(_texture_pixels(scene.model, f"distractor_{j}_mat"),
                                      surface_maps(cfg, d.material).albedo)


def test_a_cc0_set_is_a_full_material_in_the_pbr_profile(small_config, texture_dir):
    cfg = small_config.replace(**{"materials.textures": str(texture_dir), "render.profile": "pbr",
                                  "camera.width": 64, "camera.height": 48})
    maps = surface_maps(cfg, "folder:Tiles01")
    assert (maps.roughness == 90).all() and (maps.normal == (128, 128, 255)).all()
    for seed in range(8):  # some scene puts the set on the floor
        scene, *_ = prepare_scene(cfg, load_objects(cfg), seed)
        if scene.spec.floor.material == "folder:Tiles01":
            break
    else:
        pytest.fail("no scene drew the CC0 set for its floor")
    rough = _texture_pixels(scene.model, "floor_mat", mujoco.mjtTextureRole.mjTEXROLE_ROUGHNESS)
    np.testing.assert_array_equal(rough, np.repeat(maps.roughness[..., None], 3, axis=2))  # grey stored as RGB
    np.testing.assert_array_equal(_texture_pixels(scene.model, "floor_mat", mujoco.mjtTextureRole.mjTEXROLE_NORMAL),
                                  maps.normal)


def test_without_texture_folder_surfaces_come_from_the_library(small_config):
    scene, *_ = prepare_scene(small_config, load_objects(small_config), 0)
    keys = [scene.spec.table.material, scene.spec.floor.material, *(d.material for d in scene.spec.distractors)]
    assert all(k is not None and k.split(":")[0] in small_config.materials.families for k in keys)
    plain = small_config.replace(**{"materials.families": []})
    scene, *_ = prepare_scene(plain, load_objects(plain), 0)
    assert scene.spec.table.material is None and scene.spec.table.pattern in ("checker", "gradient", "flat")


def test_texture_folder_errors_name_the_field(small_config, tmp_path):
    with pytest.raises(ConfigError, match="materials.textures.*not a folder"):
        prepare_scene(small_config.replace(**{"materials.textures": str(tmp_path / "missing")}),
                      load_objects(small_config), 0)
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(ConfigError, match="materials.textures.*no .png"):
        prepare_scene(small_config.replace(**{"materials.textures": str(tmp_path)}), load_objects(small_config), 0)
