"""BOP models export and read back: geometry (< 1e-6 m) and metadata survive the round trip."""

from __future__ import annotations

import json

import numpy as np
import trimesh

from simtest.io.bop_models import MM_PER_M, write_bop_models
from simtest.objects import read_bop_models


def test_round_trip(tmp_path, builtin):
    out = write_bop_models(builtin, tmp_path / "models")
    back = read_bop_models(out)
    assert back.ids == builtin.ids
    for a, b in zip(builtin, back):
        assert np.abs(a.vertices - b.vertices).max() < 1e-6
        np.testing.assert_array_equal(a.faces, b.faces)
        assert (a.name, a.category, a.instance, a.density, a.rgba) == (b.name, b.category, b.instance, b.density,
                                                                       b.rgba)
        assert len(a.symmetries_discrete) == len(b.symmetries_discrete)
        for Ta, Tb in zip(a.symmetries_discrete, b.symmetries_discrete):
            np.testing.assert_allclose(Ta, Tb, atol=1e-12)
        assert a.symmetries_continuous == b.symmetries_continuous
        assert abs(a.diameter - b.diameter) < 1e-6


def test_models_info_as_bop_toolkit_reads_it(tmp_path, builtin_small):
    out = write_bop_models(builtin_small, tmp_path / "models")
    info = json.loads((out / "models_info.json").read_text())
    assert sorted(info, key=int) == [str(i) for i in sorted(builtin_small.ids)]
    for obj in builtin_small:
        entry = info[str(obj.obj_id)]
        assert abs(entry["diameter"] - obj.diameter * MM_PER_M) < 1e-6
        for i, ax in enumerate("xyz"):
            assert abs(entry[f"min_{ax}"] - obj.bbox[0][i] * MM_PER_M) < 1e-9
            assert abs(entry[f"size_{ax}"] - obj.size[i] * MM_PER_M) < 1e-9
        for flat in entry.get("symmetries_discrete", []):
            assert len(flat) == 16
        # the PLY is in millimetres with normals and colours (texture coordinates and the texture next to it for
        # a textured object, as the built-ins are), and faces as vertex_indices
        ply = out / f"obj_{obj.obj_id:06d}.ply"
        header = ply.read_bytes().split(b"end_header")[0].decode()
        textured = obj.appearance is not None and obj.appearance.kind == "texture"
        looks = ("property float texture_u", f"comment TextureFile obj_{obj.obj_id:06d}.png") if textured else (
            "property uchar red",)
        for prop in ("property float nx", "property list uchar int vertex_indices", "binary_little_endian", *looks):
            assert prop in header
        assert (out / f"obj_{obj.obj_id:06d}.png").is_file() == textured
        mesh = trimesh.load(ply, process=False)
        # vertices are split where UVs differ: every face corner is at the same place, in the same order
        np.testing.assert_allclose(mesh.vertices[mesh.faces], obj.vertices[obj.faces] * MM_PER_M, atol=1e-3)
    assert "symmetries_continuous" in info["1"] and info["1"]["symmetries_continuous"][0]["offset"] == [0, 0, 0]
    assert "symmetries_continuous" not in info["7"] and "symmetries_discrete" not in info["7"]  # mug
    assert len(info["13"]["symmetries_discrete"]) == 3  # box


def test_no_temporary_files_left(tmp_path, builtin_small):
    out = write_bop_models(builtin_small, tmp_path / "models")
    names = sorted(p.name for p in out.iterdir())
    textures = [f"obj_{o.obj_id:06d}.png" for o in builtin_small if o.appearance is not None]
    assert names == sorted([f"obj_{i:06d}.ply" for i in builtin_small.ids] + textures
                           + ["models_info.json", "simtest_objects.json"])
