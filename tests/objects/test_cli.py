"""``simtest objects`` sub-commands through ``simtest.cli.main``."""

from __future__ import annotations

import numpy as np
import pytest

from simtest.cli import main
from simtest.objects import load_object_set


def test_list_prints_every_builtin(capsys):
    assert main(["objects", "list", "--set", "builtin", "--no-grasps"]) == 0
    out = capsys.readouterr().out
    for obj in load_object_set("builtin"):
        assert f" {obj.name} " in out
    assert "diam_mm" in out and "continuous(z)" in out and "discrete(7)" in out


def test_list_small_with_grasps(capsys):
    assert main(["objects", "list", "--set", "builtin-small"]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert len(lines) == 2 + 4
    assert all(line.split()[-2] == "yes" for line in lines[2:])


def test_export_refuses_non_empty(tmp_path, capsys):
    out = tmp_path / "models"
    out.mkdir()
    (out / "keep.txt").write_text("x")
    assert main(["objects", "export", "--set", "builtin-small", "--out", str(out)]) == 2
    assert "not empty" in capsys.readouterr().err
    assert main(["objects", "export", "--set", "builtin-small", "--out", str(out), "--overwrite"]) == 0
    assert (out / "models_info.json").exists() and (out / "obj_000022.ply").exists()


def test_unknown_set_is_an_error(capsys):
    assert main(["objects", "list", "--set", "no-such-set"]) == 2
    assert "builtin-small" in capsys.readouterr().err


def test_preview_unknown_id(tmp_path, capsys):
    assert main(["objects", "preview", "99", "--set", "builtin-small", "--out", str(tmp_path / "p.png")]) == 2
    assert "known ids" in capsys.readouterr().err


def test_preview_renders(tmp_path):
    pytest.importorskip("mujoco")
    out = tmp_path / "mug.png"
    assert main(["objects", "preview", "7", "--set", "builtin-small", "--out", str(out), "--size", "96"]) == 0
    from PIL import Image

    img = np.asarray(Image.open(out))
    assert img.shape == (96, 4 * 96, 3)
    assert img.std() > 5  # the object is visible, not a blank frame


def test_library_warnings_are_one_line_without_simtest_file_and_line(tmp_path, monkeypatch, capsys, recwarn):
    """A mesh that is not watertight: the loader's note reaches the terminal as ``simtest: warning: ...``, one
    line, with no file:line of simtest's code and no Python warning; -vv adds the logger's name."""
    import trimesh

    monkeypatch.setenv("SIMTEST_CACHE", str(tmp_path / "cache"))
    box = trimesh.creation.box(extents=(0.05, 0.04, 0.03))
    trimesh.Trimesh(box.vertices, box.faces[:-2]).export(tmp_path / "open.ply")
    assert main(["objects", "list", "--set", str(tmp_path / "open.ply"), "--no-grasps"]) == 0
    err = capsys.readouterr().err.splitlines()
    (line,) = [e for e in err if "open.ply" in e]
    assert line.startswith("simtest: warning: ") and "not watertight" in line, err
    assert not any(".py:" in e or "UserWarning" in e for e in err), err
    assert not [w for w in recwarn if issubclass(w.category, UserWarning) and "simtest" in str(w.filename)]
    assert main(["objects", "list", "--set", str(tmp_path / "open.ply"), "--no-grasps", "-vv"]) == 0
    err = capsys.readouterr().err
    assert "simtest: warning: simtest.objects.loaders: " in err
