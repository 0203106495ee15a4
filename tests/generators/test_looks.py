"""Appearance (materials, environments, object prints) is drawn apart from geometry: ground truth is identical
with and without it, and the same seed gives the same materials."""

from __future__ import annotations

import filecmp
from pathlib import Path

import numpy as np
import pytest

from simtest.generators.config import GenerateConfig
from simtest.generators.looks import appearance_rng, sample_environment
from simtest.generators.pipeline import generate, load_objects, prepare_scene
from simtest.rng import child_rng

#: Files and folders of a scene that carry ground truth (rgb/ is what appearance changes).
GT_PARTS = ("scene_gt.json", "scene_gt_info.json", "scene_camera.json", "depth", "mask", "mask_visib")


def _config(**extra) -> GenerateConfig:
    return GenerateConfig().replace(**{
        "objects": "builtin-small", "scenes": 1, "frames_per_scene": 2, "camera.width": 96, "camera.height": 72,
        "scene.objects_per_scene": [3, 3], "scene.distractors": [2, 2], "seed": 11, **extra})


PLAIN = {"materials.families": [], "materials.object_textures": False, "lights.environment": "constant"}


def _same_tree(a: Path, b: Path) -> list[str]:
    """Relative paths under ``a`` whose bytes differ in ``b`` (or are missing there)."""
    bad = []
    for f in sorted(p for p in a.rglob("*") if p.is_file()):
        g = b / f.relative_to(a)
        if not g.is_file() or not filecmp.cmp(f, g, shallow=False):
            bad.append(str(f.relative_to(a)))
    return bad


def _ground_truth_differs(a: Path, b: Path) -> list[str]:
    bad = []
    for scene in sorted((a / "train_pbr").iterdir()):
        for part in GT_PARTS:
            x, y = scene / part, b / "train_pbr" / scene.name / part
            bad += [f"{scene.name}/{part}/{r}" for r in _same_tree(x, y)] if x.is_dir() else (
                [] if filecmp.cmp(x, y, shallow=False) else [f"{scene.name}/{part}"])
    return bad


@pytest.fixture(scope="module")
def looks_runs(tmp_path_factory):
    root = tmp_path_factory.mktemp("looks")
    runs = {"default": _config(), "again": _config(), "plain": _config(**PLAIN),
            "other_families": _config(**{"materials.families": ["concrete", "fabric"],
                                          "lights.environment": "studio"}),
            "unseen_variants": _config(**{"materials.first_variant": 1000})}
    for name, cfg in runs.items():
        generate(cfg, root / name, progress=False)
    return root


def test_ground_truth_is_identical_with_and_without_materials(looks_runs):
    for other in ("plain", "other_families", "unseen_variants"):
        assert _ground_truth_differs(looks_runs / "default", looks_runs / other) == [], other
    rgb = sorted((looks_runs / "default" / "train_pbr" / "000000" / "rgb").iterdir())
    assert any(not filecmp.cmp(f, looks_runs / "plain" / "train_pbr" / "000000" / "rgb" / f.name, shallow=False)
               for f in rgb), "materials changed no pixel"


def test_same_seed_same_materials(looks_runs):
    a, b = looks_runs / "default" / "train_pbr", looks_runs / "again" / "train_pbr"
    assert [p for p in _same_tree(a, b) if not p.endswith("scene_info.json")] == []


def test_the_geometry_stream_is_untouched_by_appearance():
    rng = child_rng(3, 0, 0)
    before = rng.bit_generator.state
    look = appearance_rng(rng)
    sample_environment(_config(), look)
    assert rng.bit_generator.state == before
    assert appearance_rng(child_rng(3, 0, 0)).integers(1 << 30) == appearance_rng(child_rng(3, 0, 0)).integers(1 << 30)


def test_pbr_reads_the_material_maps(tmp_path):
    pytest.importorskip("mitsuba")
    cfg = _config(**{"render.profile": "pbr", "render.pbr_spp": 1, "frames_per_scene": 1,
                     "lights.environment": "sky"})
    scene, *_ = prepare_scene(cfg, load_objects(cfg), 0)
    m = scene.model
    import mujoco

    rough = m.mat_texid[:, int(mujoco.mjtTextureRole.mjTEXROLE_ROUGHNESS)]
    normal = m.mat_texid[:, int(mujoco.mjtTextureRole.mjTEXROLE_NORMAL)]
    assert (rough >= 0).sum() >= 3 and (normal >= 0).sum() >= 3  # table, floor, walls (+ distractors)
    generate(cfg, tmp_path / "pbr", progress=False)
    generate(cfg, tmp_path / "pbr_again", progress=False)
    generate(_config(**{**PLAIN, "frames_per_scene": 1}), tmp_path / "plain", progress=False)
    assert _ground_truth_differs(tmp_path / "plain", tmp_path / "pbr") == []
    same = [p for p in _same_tree(tmp_path / "pbr" / "train_pbr", tmp_path / "pbr_again" / "train_pbr")
            if not p.endswith("scene_info.json")]
    assert same == []  # same seed, same materials and environment, same bytes


def test_fast_profile_uploads_colour_maps_only():
    cfg = _config()
    scene, *_ = prepare_scene(cfg, load_objects(cfg), 0)
    import mujoco

    m = scene.model
    assert (m.mat_texid[:, int(mujoco.mjtTextureRole.mjTEXROLE_NORMAL)] < 0).all()
    assert (m.mat_texid[:, int(mujoco.mjtTextureRole.mjTEXROLE_RGB)] >= 0).sum() >= 3


def test_bop_pbr_recipe_builds_its_room(tmp_path):
    cfg = _config(**{"recipe": "bop-pbr"})
    assert cfg.frames_per_scene == 2 and cfg.scene.table_height == 0.0 and cfg.shell.distance == (0.61, 1.24)
    scene, *_ = prepare_scene(cfg, load_objects(cfg), 0)
    import mujoco

    names = {mujoco.mj_id2name(scene.model, mujoco.mjtObj.mjOBJ_GEOM, g) for g in range(scene.model.ngeom)}
    assert "ceiling" in names and "table_top" not in names
    assert scene.spec.floor.material == scene.spec.walls.material  # one material for the room
    assert scene.spec.ceiling is not None and 0.15 <= np.mean(scene.spec.ceiling) <= 0.6
    generate(cfg, tmp_path / "bop", progress=False)
    assert len(list((tmp_path / "bop" / "train_pbr" / "000000" / "rgb").iterdir())) == 2


def test_hdri_folder_lights_pbr_and_keeps_ground_truth(tmp_path):
    pytest.importorskip("mitsuba")
    import cv2

    folder = tmp_path / "hdri"
    folder.mkdir()
    env = np.full((32, 64, 3), 0.3, np.float32)
    env[4:8, 20:24] = 60.0  # a small bright source high in the sky
    assert cv2.imwrite(str(folder / "sky.hdr"), env[..., ::-1].copy())
    (folder / "notes.txt").write_text("not a map")
    cfg = _config(**{"render.profile": "pbr", "render.pbr_spp": 1, "frames_per_scene": 1,
                     "lights.hdri": str(folder)})
    scene, *_ = prepare_scene(cfg, load_objects(cfg), 0)
    assert scene.spec.environment.kind == "hdri" and scene.spec.environment.source.endswith("sky.hdr")
    assert scene.model.nlight == 0  # the map alone lights the pbr profile
    generate(cfg, tmp_path / "lit", progress=False)
    generate(_config(**{**PLAIN, "frames_per_scene": 1}), tmp_path / "plain", progress=False)
    assert _ground_truth_differs(tmp_path / "plain", tmp_path / "lit") == []
    fast = _config(**{"frames_per_scene": 1, "lights.hdri": str(folder)})
    scene, *_ = prepare_scene(fast, load_objects(fast), 0)
    assert scene.model.nlight >= 1  # the rasterizer draws the map's dominant direction as a light


def test_unknown_family_and_bad_weights_are_refused():
    from simtest.errors import ConfigError

    with pytest.raises(ConfigError, match="materials.families"):
        _config(**{"materials.families": ["wood", "lava"]})
    with pytest.raises(ConfigError, match="family_weights"):
        _config(**{"materials.families": ["wood", "tiles"], "materials.family_weights": [1.0]})
    with pytest.raises(ConfigError, match="lights.hdri"):
        sample_environment(_config(**{"lights.environment": "hdri"}), appearance_rng(child_rng(0, 0)))


def test_first_variant_draws_looks_no_default_run_draws(looks_runs):
    """``materials.first_variant`` shifts every appearance seed (materials, environment, prints) past the
    default range, the same draws otherwise: a test set whose looks a training set never saw."""
    import json

    def looks(name):
        spec = json.loads((looks_runs / name / "train_pbr" / "000000" / "scene_info.json").read_text())["spec"]
        return spec

    default, unseen = looks("default"), looks("unseen_variants")
    seeds = [p["skin_seed"] for p in default["objects"] if p.get("skin_seed") is not None]
    shifted = [p["skin_seed"] for p in unseen["objects"] if p.get("skin_seed") is not None]
    assert seeds and shifted == [s + 1000 for s in seeds]
    assert all(0 <= s < 12 for s in seeds)
    text_default, text_unseen = json.dumps(default), json.dumps(unseen)
    assert text_default != text_unseen
    rgb = looks_runs / "default" / "train_pbr" / "000000" / "rgb"
    assert any(not filecmp.cmp(f, looks_runs / "unseen_variants" / "train_pbr" / "000000" / "rgb" / f.name,
                               shallow=False) for f in sorted(rgb.iterdir())), "the unseen looks changed no pixel"
