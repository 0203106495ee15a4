"""Many classes: a 150-object mesh library in 30 categories is read lazily, its scenes read only the objects they
use (and examine only those: symmetry and collision caches on disk), ground truth is right, ``objects list``
shows categories and ``eval`` reports per-category viewpoint accuracy."""

from __future__ import annotations

import json

import cv2
import numpy as np
import pytest

from simtest.benchmarks.objects import SHAPES, write_mesh_tree
from simtest.camera import CameraModel
from simtest.io.bop import read_mask, read_scene, scene_dirs

N_OBJECTS, N_CATEGORIES = 150, 30


@pytest.fixture(scope="module")
def tree(tmp_path_factory):
    return write_mesh_tree(tmp_path_factory.mktemp("library") / "meshes", N_OBJECTS, N_CATEGORIES, seed=3)


@pytest.fixture(scope="module")
def library_dataset(tree, tmp_path_factory):
    """One scene of 3 frames from the library, generated against an empty on-disk cache."""
    from simtest.generators.config import GenerateConfig
    from simtest.generators.pipeline import generate

    base = tmp_path_factory.mktemp("libds")
    mp = pytest.MonkeyPatch()
    mp.setenv("SIMTEST_CACHE", str(base / "cache"))
    cfg = GenerateConfig().replace(**{
        "objects": str(tree), "scenes": 1, "frames_per_scene": 3, "camera.width": 160, "camera.height": 120,
        "scene.objects_per_scene": [6, 6], "scene.allow_repeats": False, "scene.distractors": [0, 0],
        "seed": 11})
    try:
        generate(cfg, base / "ds", progress=False)
    finally:
        mp.undo()
    return base / "ds", base / "cache"


def _used_ids(dataset) -> set[int]:
    return {g.obj_id for d in scene_dirs(dataset / "train_pbr") for im in read_scene(d).values() for g in im["gt"]}


def test_tree_loads_names_and_categories_without_reading_meshes(tree, tmp_path, monkeypatch):
    import simtest.objects.loaders as loaders
    from simtest.objects import load_object_set
    from simtest.objects.lazy import LazyObjectSet

    monkeypatch.setenv("SIMTEST_CACHE", str(tmp_path / "cache"))
    reads = []
    real = loaders.load_mesh
    monkeypatch.setattr(loaders, "load_mesh", lambda path: reads.append(str(path)) or real(path))
    objects = load_object_set(tree)
    assert isinstance(objects, LazyObjectSet) and len(objects) == N_OBJECTS and reads == []
    assert objects.categories == sorted(f"cat{c:03d}_{SHAPES[c % len(SHAPES)]}" for c in range(N_CATEGORIES))
    entries = objects.entries
    assert [e.obj_id for e in entries] == list(range(1, N_OBJECTS + 1))  # sorted paths -> 1..N
    assert sorted(e.source for e in entries) == [e.source for e in entries]
    per_cat = {c: sum(e.category == c for e in entries) for c in objects.categories}
    assert set(per_cat.values()) == {N_OBJECTS // N_CATEGORIES}
    assert all(e.source.split("/")[-2] == e.category for e in entries)
    assert objects.loaded_ids == [] and not (tmp_path / "cache" / "symmetry").exists()
    # One object is read on request: its mesh, its symmetries (cached on disk), nothing else.
    mug = objects.get(37)
    assert (mug.obj_id, mug.category) == (37, entries[36].category) and mug.extra["symmetry"] == "detected"
    assert reads == [entries[36].source] and objects.loaded_ids == [37]
    assert [p.name.split("_")[0] for p in (tmp_path / "cache" / "symmetry").iterdir()] == [mug.mesh_hash]
    # the same files give the same ids, names and categories again
    assert load_object_set(tree).entries == entries


def test_scene_reads_and_examines_only_the_objects_it_uses(library_dataset, tree):
    from simtest.objects import load_object_set

    dataset, cache = library_dataset
    used = _used_ids(dataset)
    assert 1 <= len(used) <= 6
    info = json.loads((dataset / "models" / "models_info.json").read_text())
    assert {int(k) for k in info} == used  # models of the used objects only
    manifest = json.loads((dataset / "manifest.json").read_text())
    assert len(manifest["objects"]) == N_OBJECTS and manifest["objects"][40]["category"].startswith("cat")
    # Symmetry detection ran for exactly the objects the scene drew (one cache file per mesh hash), and no
    # collision decomposition for any other object.
    objects = load_object_set(tree, symmetry="none")
    drawn = json.loads((scene_dirs(dataset / "train_pbr")[0] / "scene_info.json").read_text())["spec"]["objects"]
    drawn_hashes = {objects.get(p["obj_id"]).mesh_hash for p in drawn}
    cached = {p.name.split("_")[0] for p in (cache / "symmetry").iterdir()}
    assert cached == drawn_hashes and len(cached) <= 6
    coacd = {p.name.split("_")[0] for p in (cache / "coacd").iterdir()} if (cache / "coacd").exists() else set()
    assert coacd <= drawn_hashes


def test_scene_ground_truth_reprojects_onto_masks(library_dataset):
    """Model vertices through the GT pose and K fall on the amodal mask (the ground-truth check of
    tests/generators/test_ground_truth.py on the library's models)."""
    from simtest.objects.loaders import load_dataset_objects

    dataset, _ = library_dataset
    objects = load_dataset_objects(dataset)
    checked = 0
    for scene_dir in scene_dirs(dataset / "train_pbr"):
        for im_id, im in read_scene(scene_dir).items():
            for gt_id, gt in enumerate(im["gt"]):
                if gt.px_count_visib < 30:
                    continue
                cam = CameraModel(im["K"], 160, 120)
                uv, _ = cam.project(gt.T_cam_obj.apply(objects.get(gt.obj_id).vertices))
                px = np.round(uv).astype(int)
                inside = (px[:, 0] >= 0) & (px[:, 0] < 160) & (px[:, 1] >= 0) & (px[:, 1] < 120)
                amodal = read_mask(scene_dir, im_id, gt_id, visible=False)
                grown = cv2.dilate(amodal.astype(np.uint8), np.ones((3, 3), np.uint8)) > 0
                assert grown[px[inside, 1], px[inside, 0]].mean() > 0.99
                checked += 1
    assert checked >= 3


def test_same_seed_same_scene_spec(tree):
    from simtest.generators.config import GenerateConfig
    from simtest.generators.scene_spec import sample_scene_spec
    from simtest.objects import load_object_set
    from simtest.rng import child_rng

    cfg = GenerateConfig().replace(**{"objects": str(tree), "scene.objects_per_scene": [5, 5]})
    a = sample_scene_spec(cfg, load_object_set(tree, symmetry="none"), child_rng(4, 0, 0), 0)
    b = sample_scene_spec(cfg, load_object_set(tree, symmetry="none"), child_rng(4, 0, 0), 0)
    assert a.to_dict() == b.to_dict()


def test_objects_list_shows_categories(tree, tmp_path, monkeypatch, capsys):
    from simtest.cli import main

    monkeypatch.setenv("SIMTEST_CACHE", str(tmp_path / "cache"))
    assert main(["objects", "list", "--set", str(tree), "--by-category"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].endswith(f"{N_OBJECTS} objects in {N_CATEGORIES} categories")
    assert lines[1].split() == ["category", "objects", "obj_ids"] and len(lines) == 2 + N_CATEGORIES
    assert lines[2].split() == ["cat000_box", "5", "1-5"]
    assert main(["objects", "list", "--set", str(tree)]) == 0  # category table, then every instance
    out = capsys.readouterr().out
    rows = [line.split() for line in out.splitlines()]
    assert ["cat029_prism", "5", "146-150"] in rows and rows[-1][-1] == "cat029_prism/prism_004.ply"
    assert not (tmp_path / "cache" / "symmetry").exists()  # no mesh was examined
    assert main(["objects", "list", "--set", str(tree), "--category", "cat001_cylinder", "--no-grasps"]) == 0
    rows = capsys.readouterr().out.splitlines()[2:]
    assert len(rows) == 5 and all("detected" in r and "cat001_cylinder" in r for r in rows)
    assert main(["objects", "list", "--set", str(tree), "--category", "nope"]) == 2
    assert "unknown category nope; known: cat000_box" in capsys.readouterr().err


def _rotated(R: np.ndarray, degrees: float) -> np.ndarray:
    """``R`` turned by ``degrees`` about the object's x axis: the geodesic error is ``degrees``, and stays near
    it over the symmetries (the shapes' symmetry axes are z or flips, x at most slightly tilted by shear)."""
    a = np.radians(degrees)
    Rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    return R @ Rx


def test_per_category_viewpoint_accuracy_from_a_results_file(library_dataset, tmp_path):
    """A hand-made results file: every object of one category 20 deg off (Acc@pi/6 1, Acc@pi/18 0), of
    another 5 deg off (1, 1), the others missing (0, 0); the category table says exactly that."""
    from simtest.evaluation.run import score_results
    from simtest.io.bop_results import write_bop_results
    from simtest.metrics.bop19 import ResultRow
    from simtest.objects.loaders import load_dataset_objects

    dataset, _ = library_dataset
    objects = load_dataset_objects(dataset)
    cats = sorted({objects.get(i).category for i in _used_ids(dataset)})
    assert len(cats) >= 2
    off = {cats[0]: 20.0, cats[1]: 5.0}
    rows = []
    for scene_dir in scene_dirs(dataset / "train_pbr"):
        for im_id, im in read_scene(scene_dir).items():
            for gt in im["gt"]:
                deg = off.get(objects.get(gt.obj_id).category)
                if deg is not None:
                    rows.append(ResultRow(int(scene_dir.name), im_id, gt.obj_id, 1.0,
                                          _rotated(gt.T_cam_obj.R, deg), gt.T_cam_obj.t, 0.1))
    write_bop_results(tmp_path / "results.csv", rows)
    report = score_results(tmp_path / "results.csv", dataset, vsd=False, progress=False, out_dir=tmp_path / "out")
    per = report.per_category
    assert set(per) == set(cats)
    assert (per[cats[0]]["acc_pi_6"], per[cats[0]]["acc_pi_18"]) == (1.0, 0.0)
    assert (per[cats[1]]["acc_pi_6"], per[cats[1]]["acc_pi_18"]) == (1.0, 1.0)
    for c in cats[2:]:
        assert (per[c]["acc_pi_6"], per[c]["acc_pi_18"]) == (0.0, 0.0)
    assert sum(m["num_targets"] for m in per.values()) == report.overall["num_targets"]
    assert 15.0 < per[cats[0]]["median_re_deg"] <= 20.0 + 1e-6  # smallest over the symmetries
    md = (tmp_path / "out" / "metrics.md").read_text()
    assert f"#### Per category ({len(cats)} categories)" in md and f"| {cats[0]} |" in md
    saved = json.loads((tmp_path / "out" / "metrics.json").read_text())["per_category"]
    assert saved[cats[1]]["acc_pi_18"] == 1.0 and saved[cats[0]]["num_objects"] >= 1


def test_unlabelled_split_of_a_library_writes_the_models_its_scenes_use(library_dataset, tree, tmp_path):
    """The labels of an unlabelled split are withheld; the models written are still those its scenes use (the
    same as the labelled run with that seed)."""
    from simtest.generators.config import GenerateConfig
    from simtest.generators.pipeline import generate

    ds, _ = library_dataset
    cfg = GenerateConfig().replace(**{
        "objects": str(tree), "scenes": 1, "frames_per_scene": 3, "camera.width": 160, "camera.height": 120,
        "scene.objects_per_scene": [6, 6], "scene.allow_repeats": False, "scene.distractors": [0, 0],
        "seed": 11, "unlabelled": True})
    generate(cfg, tmp_path / "unl", progress=False)
    assert not (tmp_path / "unl" / "train_pbr" / "000000" / "scene_gt.json").exists()
    models = sorted(p.name for p in (tmp_path / "unl" / "models").glob("obj_*.ply"))
    assert models == sorted(p.name for p in (ds / "models").glob("obj_*.ply")) and len(models) == len(_used_ids(ds))
