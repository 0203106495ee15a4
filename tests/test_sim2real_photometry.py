"""docs/sim2real_photometry.py on generated datasets of vertex-coloured models: the objects' brightness against
their models' colours follows the scene's light, and models without vertex colours are refused by name."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import trimesh

from simtest.generators.config import GenerateConfig
from simtest.generators.pipeline import generate

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "docs"))

import sim2real_photometry  # noqa: E402


def _dataset(folder: Path, meshes: Path, light: tuple[float, float], coloured: bool = True) -> Path:
    meshes.mkdir(parents=True, exist_ok=True)
    box = trimesh.creation.box(extents=(0.08, 0.06, 0.05))
    can = trimesh.creation.cylinder(radius=0.03, height=0.1, sections=24)
    if coloured:
        box.visual.vertex_colors = np.tile([200, 190, 180, 255], (len(box.vertices), 1)).astype(np.uint8)
        can.visual.vertex_colors = np.tile([210, 60, 40, 255], (len(can.vertices), 1)).astype(np.uint8)
    box.export(meshes / "box.ply")
    can.export(meshes / "can.ply")
    cfg = GenerateConfig().replace(**{
        "objects": str(meshes), "scenes": 1, "frames_per_scene": 2, "camera.width": 128, "camera.height": 96,
        "scene.objects_per_scene": [4, 4], "scene.distractors": [0, 0], "materials.randomize_object_colour": False,
        "lights.count": [1, 1], "lights.intensity": list(light), "lights.ambient": [light[0] / 3, light[1] / 3],
        "lights.environment": "constant",
        "seed": 5})
    generate(cfg, folder, progress=False)
    return folder


def test_objects_brighten_with_the_light_against_their_vertex_colours(tmp_path):
    dim = _dataset(tmp_path / "dim", tmp_path / "meshes", (0.2, 0.2))
    bright = _dataset(tmp_path / "bright", tmp_path / "meshes", (0.9, 0.9))
    a, b = (sim2real_photometry.measure(d, None, None, 20) for d in (dim, bright))
    assert a["instances"] >= 4 and set(a["ratio"]) == set(b["ratio"]) == {1, 2}
    for o in (1, 2):
        assert 0.0 < a["ratio"][o] < b["ratio"][o] < 2.0
    assert float(np.mean(a["image_mean"])) < float(np.mean(b["image_mean"]))
    # the ratio, read back by hand for the box (obj 1, painted (200, 190, 180)): visible pixels over that colour
    from simtest.io import bop
    from simtest.io.bop_splits import dataset_split_dir, scene_dirs

    (scene,) = scene_dirs(dataset_split_dir(bright))
    ann, ratios = bop.read_scene(scene), []
    for im in sorted(ann):
        rgb = bop.read_image(scene, im).astype(np.float64)
        for g, gt in enumerate(ann[im]["gt"]):
            mask = bop.read_mask(scene, im, g, visible=True)
            if int(gt.obj_id) == 1 and int(mask.sum()) >= 20:
                ratios.append(float((rgb[mask].mean(0) / np.array([200.0, 190.0, 180.0])).mean()))
    assert ratios and abs(b["ratio"][1] - float(np.mean(ratios))) < 1e-9
    done = subprocess.run([sys.executable, str(ROOT / "docs" / "sim2real_photometry.py"), str(dim), str(bright)],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    lines = done.stdout.splitlines()
    assert len(lines) == 2 and all("of their vertex colours" in line for line in lines)


def test_models_without_vertex_colours_are_named(tmp_path):
    plain = _dataset(tmp_path / "plain", tmp_path / "meshes", (0.5, 0.5), coloured=False)
    for path in (plain / "models").glob("obj_*.ply"):  # BOP models as some sets ship them: geometry only
        mesh = trimesh.load(path, process=False)
        trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).export(path)
    done = subprocess.run([sys.executable, str(ROOT / "docs" / "sim2real_photometry.py"), str(plain)],
                          capture_output=True, text=True, timeout=300)
    assert done.returncode != 0 and "no BOP model (obj_*.ply) with vertex colours" in done.stderr
    assert "obj_000001.ply: no vertex colours, skipped" in done.stderr
