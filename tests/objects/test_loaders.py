"""Mesh and BOP loaders: units, centring, ids, and clear errors for bad input."""

from __future__ import annotations

import json
import logging
import re

import numpy as np
import pytest
import trimesh

from simtest.errors import AssetError
from simtest.objects import load_mesh_file, load_object_set
from simtest.io.bop_models import write_bop_models


def assert_logged(caplog, pattern: str) -> None:
    """One warning line of ``simtest.objects.loaders`` matches ``pattern`` (logged, not a Python warning)."""
    lines = [r.getMessage() for r in caplog.records
             if r.name == "simtest.objects.loaders" and r.levelno == logging.WARNING]
    assert any(re.search(pattern, line) and "\n" not in line for line in lines), lines


def box_mesh(size_m=(0.05, 0.04, 0.03), offset=(0.1, 0.2, 0.3)) -> trimesh.Trimesh:
    m = trimesh.creation.box(extents=size_m)
    m.apply_translation(offset)
    return m


def test_single_file_metres_is_recentred(tmp_path):
    path = tmp_path / "thing.obj"
    box_mesh().export(path)
    (obj,) = load_object_set(path, units="m")
    np.testing.assert_allclose(obj.size, [0.05, 0.04, 0.03], atol=1e-9)
    np.testing.assert_allclose(obj.bbox.sum(axis=0), 0.0, atol=1e-12)
    np.testing.assert_allclose(obj.extra["origin_offset"], [0.1, 0.2, 0.3], atol=1e-9)
    assert obj.obj_id == 1 and obj.name == "thing"


def test_millimetre_file(tmp_path):
    path = tmp_path / "part.stl"
    box_mesh((50.0, 40.0, 30.0), (0, 0, 0)).export(path)
    (obj,) = load_object_set(path, units="mm")
    np.testing.assert_allclose(obj.size, [0.05, 0.04, 0.03], atol=1e-9)
    assert obj.extra["units"] == "mm"
    assert obj.is_watertight  # STL triangles are merged into a closed mesh


def test_mm_mesh_read_as_metres_is_absurd(tmp_path):
    path = tmp_path / "big.ply"
    box_mesh((50.0, 40.0, 2000.0), (0, 0, 0)).export(path)
    with pytest.raises(AssetError, match=r"big\.ply.*2001 m across.*units='m'.*--units mm"):
        load_object_set(path, units="m")


def test_tiny_mesh_read_as_mm_suggests_metres(tmp_path):
    path = tmp_path / "small.obj"
    box_mesh((0.05, 0.04, 0.03), (0, 0, 0)).export(path)
    with pytest.raises(AssetError, match=r"small\.obj.*degenerate.*0\.0707 mm.*--units m"):
        load_object_set(path, units="mm")


def test_folder_ids_sorted_names(tmp_path):
    for name in ("zeta.obj", "alpha.ply", "mid.stl"):
        box_mesh().export(tmp_path / name)
    (tmp_path / "notes.txt").write_text("not a mesh")
    objs = load_object_set(tmp_path, units="m")
    assert [(o.obj_id, o.name) for o in objs] == [(1, "alpha"), (2, "mid"), (3, "zeta")]


def test_folder_ids_from_bop_names(tmp_path):
    box_mesh().export(tmp_path / "obj_000005.ply")
    box_mesh((0.02, 0.02, 0.02)).export(tmp_path / "obj_000002.obj")
    objs = load_object_set(tmp_path)
    assert objs.ids == [2, 5]
    with pytest.raises(AssetError, match=r"unknown object id 3.*known ids: 2 \(obj_000002\), 5 \(obj_000005\)"):
        objs.get(3)


def test_duplicate_ids(tmp_path):
    box_mesh().export(tmp_path / "obj_000005.ply")
    box_mesh().export(tmp_path / "obj_005.obj")
    with pytest.raises(AssetError, match="duplicate obj_id 5.*obj_000005.ply.*obj_005.obj"):
        load_object_set(tmp_path)


def test_missing_path():
    with pytest.raises(AssetError, match="not found.*builtin"):
        load_object_set("/nonexistent/models")
    with pytest.raises(AssetError, match="mesh file not found"):
        load_mesh_file("/nonexistent/a.ply")


def test_unreadable_file(tmp_path):
    path = tmp_path / "broken.ply"
    path.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 99\ngarbage\n")
    with pytest.raises(AssetError, match=r"broken\.ply"):
        load_object_set(path)


def test_unsupported_extension(tmp_path):
    path = tmp_path / "mesh.fbx"
    path.write_text("x")
    with pytest.raises(AssetError, match="unsupported mesh format '.fbx'"):
        load_mesh_file(path)


def test_empty_mesh(tmp_path):
    path = tmp_path / "empty.obj"
    path.write_text("# nothing here\n")
    with pytest.raises(AssetError, match=r"empty\.obj.*empty"):
        load_object_set(path)


def test_degenerate_mesh(tmp_path):
    path = tmp_path / "line.obj"
    path.write_text("v 0 0 0\nv 0.1 0 0\nv 0.2 0 0\nf 1 2 3\n")
    with pytest.raises(AssetError, match=r"line\.obj.*degenerate"):
        load_object_set(path, units="m")


def test_nan_vertices(tmp_path):
    path = tmp_path / "nan.obj"
    path.write_text("v 0 0 0\nv 0.1 0 0\nv 0 nan 0\nv 0 0 0.1\nf 1 2 3\nf 1 3 4\nf 1 4 2\nf 2 4 3\n")
    with pytest.raises(AssetError, match=r"nan\.obj.*NaN"):
        load_object_set(path, units="m")


def test_non_watertight_warns(tmp_path, caplog):
    mesh = box_mesh()
    open_mesh = trimesh.Trimesh(mesh.vertices, mesh.faces[:-2])
    path = tmp_path / "open.ply"
    open_mesh.export(path)
    with caplog.at_level(logging.WARNING, logger="simtest"):
        (obj,) = load_object_set(path, units="m")
    assert_logged(caplog, r"open\.ply.*not watertight")
    assert obj.mass > 0


def test_bad_units():
    with pytest.raises(AssetError, match="units must be one of m, cm, mm, auto"):
        load_object_set("builtin", units="inch")


def test_bop_folder_symmetries_in_mm(tmp_path):
    models = tmp_path / "models"
    models.mkdir()
    box_mesh((60.0, 40.0, 20.0), (0, 0, 0)).export(models / "obj_000003.ply")
    flip = np.diag([-1.0, -1.0, 1.0, 1.0])
    flip[:3, 3] = [0.0, 0.0, 5.0]  # mm
    info = {"3": {"diameter": 74.8, "min_x": -30, "min_y": -20, "min_z": -10, "size_x": 60, "size_y": 40,
                  "size_z": 20, "symmetries_discrete": [flip.reshape(-1).tolist()],
                  "symmetries_continuous": [{"axis": [0, 0, 1], "offset": [0, 0, 7.0]}]}}
    (models / "models_info.json").write_text(json.dumps(info))
    objs = load_object_set(tmp_path)  # the dataset root works too
    obj = objs.get(3)
    np.testing.assert_allclose(obj.size, [0.06, 0.04, 0.02], atol=1e-9)
    np.testing.assert_allclose(obj.symmetries_discrete[0][:3, 3], [0, 0, 0.005])
    np.testing.assert_allclose(obj.symmetries_continuous[0].offset, [0, 0, 0.007])


def test_bop_folder_errors(tmp_path):
    models = tmp_path / "models"
    models.mkdir()
    (models / "models_info.json").write_text(json.dumps({"4": {"diameter": 10}}))
    with pytest.raises(AssetError, match=r"obj_000004\.ply.*not found"):
        load_object_set(models)
    box_mesh((60.0, 40.0, 20.0), (0, 0, 0)).export(models / "obj_000004.ply")
    (models / "models_info.json").write_text(json.dumps({"4": {"symmetries_discrete": [[1, 2, 3]]}}))
    with pytest.raises(AssetError, match=r"models_info\.json \(obj_id 4\).*symmetries_discrete\[0\].*16"):
        load_object_set(models)
    (models / "models_info.json").write_text(json.dumps({"x": {}}))
    with pytest.raises(AssetError, match="positive integer object ids, got 'x'"):
        load_object_set(models)
    (models / "models_info.json").write_text("{not json")
    with pytest.raises(AssetError, match=r"models_info\.json: cannot read JSON"):
        load_object_set(models)


def test_written_bop_models_load_through_load_object_set(tmp_path, builtin_small):
    write_bop_models(builtin_small, tmp_path / "models")
    objs = load_object_set(tmp_path / "models", units="auto")
    assert objs.ids == sorted(builtin_small.ids)


# --- units and scale ---------------------------------------------------------------------------------------
def test_centimetre_units_and_scale(tmp_path):
    path = tmp_path / "can.obj"
    box_mesh((6.0, 6.0, 12.0), (0, 0, 0)).export(path)  # a can modelled in centimetres
    (obj,) = load_object_set(path, units="cm")
    np.testing.assert_allclose(obj.size, [0.06, 0.06, 0.12], atol=1e-9)
    assert obj.extra["units"] == "cm"
    (half,) = load_object_set(path, units="cm", scale=0.5)
    np.testing.assert_allclose(half.size, [0.03, 0.03, 0.06], atol=1e-9)
    (same,) = load_object_set(path, units="m", scale=0.01)
    np.testing.assert_allclose(same.size, obj.size, atol=1e-12)


def test_auto_refuses_a_unitless_mesh_of_1_65_m_with_the_flag_that_fits(tmp_path):
    path = tmp_path / "duck.obj"
    mesh = trimesh.creation.icosphere(subdivisions=2, radius=0.825)  # 1.65 units across, really centimetres
    mesh.export(path)
    with pytest.raises(AssetError, match=r"duck\.obj: mesh is 1\.65 units across.*1\.65 m read as metres.*"
                                         r"1 cm|0\.01 \.\. 1\.5 m") as err:
        load_object_set(path)
    assert "--units cm" in str(err.value) and "--scale 0.01" in str(err.value)
    (duck,) = load_object_set(path, units="cm")
    assert abs(duck.diameter - 0.0165) < 1e-4
    (kept,) = load_object_set(path, units="m")  # explicit metres keep a 1.65 m object
    assert abs(kept.diameter - 1.65) < 1e-2


def test_auto_refuses_tiny_and_bad_scale(tmp_path):
    path = tmp_path / "speck.stl"
    box_mesh((0.003, 0.002, 0.001), (0, 0, 0)).export(path)
    with pytest.raises(AssetError, match=r"speck\.stl.*--scale 10"):
        load_object_set(path)
    with pytest.raises(AssetError, match=r"speck\.stl: mesh is degenerate.*below 5 mm"):
        load_object_set(path, units="m")
    with pytest.raises(AssetError, match=r"scale must be a number > 0.*-1"):
        load_object_set(path, units="m", scale=-1)


def test_generate_config_and_cli_accept_units_and_scale():
    from simtest.cli import build_parser
    from simtest.cli.generate import config_from_args

    args = build_parser().parse_args(["generate", "--objects", "x", "--units", "cm", "--scale", "0.5"])
    cfg = config_from_args(args)
    assert (cfg.units, cfg.scale) == ("cm", 0.5)
    grasp = build_parser().parse_args(["grasp", "--estimator", "oracle", "--out", "o", "--units", "mm",
                                       "--scale", "2"])
    assert (grasp.units, grasp.scale) == ("mm", 2.0)


# --- manifests and folders ---------------------------------------------------------------------------------
MANIFEST = """
units = "cm"

[[object]]
file = "cans/soup.obj"
name = "soup_can"
category = "can"
symmetry = ["continuous z", "discrete 2 x"]
mass = 0.35
friction = 0.8

[[object]]
file = "box.ply"
units = "mm"
symmetry = "discrete 2 z"
graspable = false
density = 250

[[object]]
file = "tool.stl"
units = "m"
symmetry = "none"
"""


def test_manifest_names_categories_symmetries_mass(tmp_path, caplog):
    (tmp_path / "cans").mkdir()
    trimesh.creation.cylinder(radius=3.3, height=10.0).export(tmp_path / "cans" / "soup.obj")  # cm
    box_mesh((60.0, 40.0, 20.0), (0, 0, 0)).export(tmp_path / "box.ply")  # mm
    box_mesh((0.2, 0.03, 0.02), (0, 0, 0)).export(tmp_path / "tool.stl")  # m
    box_mesh().export(tmp_path / "helper.stl")  # not listed: skipped with a warning
    (tmp_path / "objects.toml").write_text(MANIFEST)
    with caplog.at_level(logging.WARNING, logger="simtest"):
        objs = load_object_set(tmp_path)
    assert_logged(caplog, r"not listed in objects\.toml skipped: helper\.stl")
    can, box, tool = objs
    assert [o.obj_id for o in objs] == [1, 2, 3]
    assert (can.name, can.category) == ("soup_can", "can")
    assert (box.name, box.category) == ("box", "box")
    np.testing.assert_allclose(box.size, [0.06, 0.04, 0.02], atol=1e-9)
    assert abs(can.diameter - np.hypot(0.066, 0.10)) < 2e-3
    assert can.symmetry_label() == "continuous(z)+discrete(1)"
    np.testing.assert_allclose(can.symmetries_discrete[0][:3, :3], np.diag([1.0, -1.0, -1.0]), atol=1e-12)
    assert abs(can.mass - 0.35) < 1e-9 and can.friction == 0.8
    assert box.symmetry_label() == "discrete(1)" and box.graspable is False and box.density == 250
    assert tool.symmetry_label() == "none" and tool.extra["symmetry"] == "declared"


def test_manifest_errors_name_the_entry(tmp_path):
    box_mesh().export(tmp_path / "a.stl")
    (tmp_path / "objects.toml").write_text('[[object]]\nfile = "a.stl"\nsymmetry = "spiral z"\n')
    with pytest.raises(AssetError, match=r"objects\.toml \[\[object\]\] #1: symmetry.*'spiral z'.*continuous"):
        load_object_set(tmp_path)
    (tmp_path / "objects.toml").write_text('[[object]]\nfile = "missing.obj"\n')
    with pytest.raises(AssetError, match=r"#1: file 'missing\.obj' not found"):
        load_object_set(tmp_path)
    (tmp_path / "objects.toml").write_text('[[object]]\nfile = "a.stl"\ncolour = "red"\n')
    with pytest.raises(AssetError, match=r"unknown key\(s\) \['colour'\]"):
        load_object_set(tmp_path)


def test_folder_tree_gives_categories(tmp_path):
    for cat, inst in (("mug", "red"), ("mug", "blue"), ("bowl", "red")):
        (tmp_path / cat).mkdir(exist_ok=True)
        box_mesh().export(tmp_path / cat / f"{inst}.obj")
    objs = load_object_set(tmp_path, units="m")
    assert sorted((o.category, o.name) for o in objs) == [("bowl", "bowl_red"), ("mug", "blue"), ("mug", "mug_red")]


def test_folder_keeps_one_file_per_base_name_preferring_the_textured_one(tmp_path, caplog):
    from tests.objects.test_appearance import write_textured_cube

    write_textured_cube(tmp_path, "mug")
    box_mesh((0.06, 0.06, 0.06), (0, 0, 0)).export(tmp_path / "mug.stl")
    box_mesh((0.06, 0.06, 0.06), (0, 0, 0)).export(tmp_path / "mug.ply")
    (tmp_path / "mug.msh").write_text("$MeshFormat\n")
    box_mesh().export(tmp_path / "plate.stl")
    with caplog.at_level(logging.WARNING, logger="simtest"):
        objs = load_object_set(tmp_path, units="m")
    assert_logged(caplog, r"mug\.obj used, mug\.ply, mug\.stl skipped.*does not read skipped: mug\.msh")
    assert [o.name for o in objs] == ["mug", "plate"]
    assert objs.by_name("mug").appearance.kind == "texture"


def test_folder_rejects_degenerate_meshes_by_name(tmp_path, caplog):
    box_mesh().export(tmp_path / "good.stl")
    box_mesh((0.004, 0.002, 0.002), (0, 0, 0)).export(tmp_path / "crumb.stl")
    (tmp_path / "points.obj").write_text("v 0 0 0\nv 0.1 0 0\nv 0 0.1 0\n")
    with caplog.at_level(logging.WARNING, logger="simtest"):
        objs = load_object_set(tmp_path, units="m")
    assert_logged(caplog, r"rejected .*crumb\.stl: mesh is degenerate.*rejected .*points\.obj.*empty")
    assert [o.name for o in objs] == ["good"]
