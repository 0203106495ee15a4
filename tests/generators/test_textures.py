"""``materials.textures`` (``--textures DIR``): image textures on the table, floor, walls and distractors."""

from __future__ import annotations

import mujoco
import numpy as np
import pytest
from PIL import Image

from simtest.errors import ConfigError
from simtest.generators.builder import load_texture_image
from simtest.generators.pipeline import load_objects, prepare_scene
from simtest.generators.scene_spec import texture_images


@pytest.fixture()
def texture_dir(tmp_path):
    y, x = np.mgrid[0:40, 0:60]
    Image.fromarray(np.stack([x * 4, y * 6, 0 * x + 90], -1).astype(np.uint8)).save(tmp_path / "ramp.png")
    checker = ((x[:, :40] // 5 + y[:, :40] // 5) % 2 * 200 + 30).astype(np.uint8)
    Image.fromarray(np.stack([checker] * 3, -1)).save(tmp_path / "checker.jpg")
    (tmp_path / "readme.txt").write_text("not an image")
    return tmp_path


def _texture_pixels(model: mujoco.MjModel, material: str) -> np.ndarray:
    mat = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_MATERIAL, material)
    tex = int(model.mat_texid[mat, int(mujoco.mjtTextureRole.mjTEXROLE_RGB)])
    w, h, adr = int(model.tex_width[tex]), int(model.tex_height[tex]), int(model.tex_adr[tex])
    return model.tex_data[adr:adr + w * h * 3].reshape(h, w, 3)


def test_texture_folder_images_cover_the_room_and_distractors(small_config, texture_dir):
    cfg = small_config.replace(**{"materials.textures": str(texture_dir), "scene.distractors": [2, 2],
                                  "camera.width": 64, "camera.height": 48})
    assert [p.rsplit("/", 1)[-1] for p in texture_images(str(texture_dir))] == ["checker.jpg", "ramp.png"]
    scene, *_ = prepare_scene(cfg, load_objects(cfg), 0)
    spec = scene.spec
    used = {spec.table.image, spec.floor.image, spec.walls.image, *(d.image for d in spec.distractors)}
    assert used <= set(texture_images(str(texture_dir))) and None not in used
    for name, surface in (("table", spec.table), ("floor", spec.floor), ("wall", spec.walls)):
        np.testing.assert_array_equal(_texture_pixels(scene.model, f"{name}_mat"), load_texture_image(surface.image))
    for j, d in enumerate(spec.distractors):
        np.testing.assert_array_equal(_texture_pixels(scene.model, f"distractor_{j}_mat"), load_texture_image(d.image))


def test_without_texture_folder_surfaces_stay_procedural(small_config):
    scene, *_ = prepare_scene(small_config, load_objects(small_config), 0)
    assert scene.spec.table.image is None and all(d.image is None for d in scene.spec.distractors)


def test_texture_folder_errors_name_the_field(small_config, tmp_path):
    with pytest.raises(ConfigError, match="materials.textures.*not a folder"):
        prepare_scene(small_config.replace(**{"materials.textures": str(tmp_path / "missing")}),
                      load_objects(small_config), 0)
    (tmp_path / "notes.txt").write_text("x")
    with pytest.raises(ConfigError, match="materials.textures.*no .png"):
        texture_images(str(tmp_path))
