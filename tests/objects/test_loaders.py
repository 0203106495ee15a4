"""Mesh and BOP loaders: units, centring, ids, and clear errors for bad input."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from simtest.errors import AssetError
from simtest.objects import load_mesh_file, load_object_set
from simtest.io.bop_models import write_bop_models


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


def test_non_watertight_warns(tmp_path):
    mesh = box_mesh()
    open_mesh = trimesh.Trimesh(mesh.vertices, mesh.faces[:-2])
    path = tmp_path / "open.ply"
    open_mesh.export(path)
    with pytest.warns(UserWarning, match=r"open\.ply.*not watertight"):
        (obj,) = load_object_set(path, units="m")
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
