"""``simtest objects prepare``: every object's collision parts computed ahead and cached, reported per object."""

from __future__ import annotations

import numpy as np
import pytest

from simtest.cli import main
from simtest.errors import AssetError
from simtest.objects import load_object_set
from simtest.objects.collision import decomposition_cache_path


def _rows(out: str) -> dict[str, list[str]]:
    lines = [line.split() for line in out.strip().splitlines()]
    assert lines[0] == ["id", "name", "collision", "parts", "seconds"]
    return {row[1]: row for row in lines[1:] if not row[0].startswith("#")}


def test_prepare_computes_then_reads_the_cache(mesh_folder, capsys, tmp_path, monkeypatch):
    args = ["objects", "prepare", "--set", str(mesh_folder), "--units", "m", "--quiet"]
    assert main(args + ["--workers", "2"]) == 0  # two worker processes fill the cache
    first = capsys.readouterr().out
    rows = _rows(first)
    assert rows["banana"][2] == "computed" and int(rows["banana"][3]) >= 2
    assert rows["box"][2:4] == ["hull", "1"]
    assert "1 decompositions computed, 0 already cached, 1 convex (hull)" in first
    objects = load_object_set(str(mesh_folder), units="m")
    banana = objects.by_name("banana")
    assert decomposition_cache_path(banana).is_file()
    assert decomposition_cache_path(objects.by_name("box")) is None
    # A run afterwards reads the parts the workers cached: the same ones.
    assert len(banana.collision_parts) == int(rows["banana"][3])
    assert main(args) == 0
    second = capsys.readouterr().out
    assert _rows(second)["banana"][2:4] == ["cached", rows["banana"][3]]
    assert "0 decompositions computed, 1 already cached" in second
    monkeypatch.setenv("SIMTEST_CACHE", str(tmp_path / "other"))  # decomposed again here, for comparison
    fresh = load_object_set(str(mesh_folder), units="m").by_name("banana").collision_parts
    assert len(fresh) == len(banana.collision_parts)
    for a, b in zip(fresh, banana.collision_parts):
        np.testing.assert_allclose(a.vertices, b.vertices)


def test_prepare_refuses_bad_input_before_any_work(tmp_path, monkeypatch, capsys):
    from simtest.objects.prepare import prepare_objects

    monkeypatch.setenv("SIMTEST_CACHE", str(tmp_path / "cache"))
    with pytest.raises(AssetError, match="not found"):
        prepare_objects(str(tmp_path / "missing"), progress=False)
    assert main(["objects", "prepare", "--set", "builtin-small", "--workers", "0", "--quiet"]) == 2
    assert "workers must be an integer >= 1; got 0" in capsys.readouterr().err
    assert not (tmp_path / "cache").exists()  # nothing was decomposed
