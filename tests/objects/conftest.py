"""Fixtures for the object tests: the built-in sets (built once per session, cached in-process) and small mesh
folders made by the tests, with their own cache."""

from __future__ import annotations

import pytest
import trimesh

from simtest.objects.builtin import build_object


@pytest.fixture(scope="session")
def builtin():
    from simtest.objects import load_object_set

    return load_object_set("builtin")


@pytest.fixture(scope="session")
def builtin_small():
    from simtest.objects import load_object_set

    return load_object_set("builtin-small")


@pytest.fixture()
def mesh_folder(tmp_path, monkeypatch):
    """A folder with a concave mesh (a banana, decomposed in under a second) and a box, and an empty cache."""
    monkeypatch.setenv("SIMTEST_CACHE", str(tmp_path / "cache"))
    folder = tmp_path / "meshes"
    folder.mkdir()
    build_object("banana", 1, seed=5).mesh.export(folder / "banana.obj")
    trimesh.creation.box([0.05, 0.04, 0.03]).export(folder / "box.obj")
    return folder
