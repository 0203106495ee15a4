"""The estimator plug-in contract: the documented example runs end to end by file path, estimators load from
files and installed entry points, PoseEstimate checks its fields, and failures carry their traceback."""

from __future__ import annotations

import csv
import json
import textwrap
from pathlib import Path

import numpy as np
import pytest

from simtest.errors import ConfigError, EstimatorError
from simtest.estimators.base import PoseEstimate
from simtest.estimators.registry import installed_estimators, load_estimator

ROOT = Path(__file__).resolve().parents[3]
EXAMPLE = f"{ROOT / 'examples' / 'my_estimator.py'}:DepthCentroid"


def _csv(path: Path) -> list[dict[str, str]]:
    with path.open(newline="") as f:
        return list(csv.DictReader(f))


# --- PoseEstimate -----------------------------------------------------------------------------------------
@pytest.mark.parametrize("kwargs, words", [
    ({"R": np.eye(4)}, "R must be a 3x3 rotation matrix (model -> camera), got shape (4, 4)"),
    ({"R": [[1, 0], [0, 1]]}, "R must be a 3x3"),
    ({"t": np.zeros(4)}, "t must be 3 values (metres, camera frame), got shape (4,)"),
    ({"t": [0.0, np.nan, 1.0]}, "t must be finite, got [0.0, nan, 1.0]"),
    ({"R": np.full((3, 3), np.inf)}, "R must be finite"),
    ({"obj_id": 1.5}, "obj_id must be an integer object id, got 1.5 (float)"),
    ({"obj_id": True}, "obj_id must be an integer object id, got True"),
    ({"t": "0 0 1"}, "t must be 3 values (metres, camera frame), got '0 0 1'"),
])
def test_pose_estimate_checks_its_fields_at_construction(kwargs, words):
    fields = {"obj_id": 3, "R": np.eye(3), "t": np.array([0.0, 0.0, 0.5]), **kwargs}
    with pytest.raises(ConfigError) as info:
        PoseEstimate(**fields)
    assert words in str(info.value) and str(info.value).startswith("PoseEstimate: ")


def test_pose_estimate_from_matrix_and_back():
    T = np.eye(4)
    T[:3, :3] = [[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]]
    T[:3, 3] = [0.01, -0.02, 0.6]
    e = PoseEstimate.from_matrix(T, np.int64(5), score=0.7, target_index=1)
    assert e.obj_id == 5 and type(e.obj_id) is int and e.score == 0.7 and e.target_index == 1
    assert e.R.dtype == np.float64 and e.t.shape == (3,) and np.array_equal(e.matrix(), T)
    T[0, 3] = 9.0  # the estimate holds copies
    assert e.t[0] == 0.01
    assert PoseEstimate(obj_id=1, R=np.eye(3).tolist(), t=[[0.0], [0.0], [1.0]]).t.shape == (3,)
    with pytest.raises(ConfigError, match=r"T must be a 4x4 matrix .*got shape \(3, 4\)"):
        PoseEstimate.from_matrix(T[:3], 5)


# --- model geometry -----------------------------------------------------------------------------------------
def test_model_geometry_copies_and_surface_cloud_with_normals():
    from simtest.estimators.icp import model_cloud
    from simtest.objects import load_object_set

    obj = load_object_set("builtin-small").by_name("can_0")
    assert not obj.vertices.flags.writeable and not obj.faces.flags.writeable
    v, f = obj.vertices_copy(), obj.faces_copy()
    v[0] += 1.0  # writable, and the model is unchanged
    assert f.flags.writeable and f.dtype == np.int32 and not np.array_equal(v[0], obj.vertices[0])
    pts, nrm = obj.surface_cloud(500)
    assert pts.shape == nrm.shape == (500, 3) and np.allclose(np.linalg.norm(nrm, axis=1), 1.0)
    assert obj.surface_cloud(500)[0] is pts  # cached
    # outward normals: on a convex can, a point moved along its normal leaves the mesh
    assert not obj.mesh.contains(pts[:50] + 0.002 * nrm[:50]).any()
    cloud = model_cloud(obj, 500)  # the icp estimator registers against the same cloud
    assert np.array_equal(cloud.points, pts) and np.array_equal(cloud.normals, nrm)


# --- the example estimator, by file path --------------------------------------------------------------------
def test_example_estimator_runs_in_eval_by_file_path(small_dataset, tmp_path, capsys):
    from simtest.cli import main

    out = tmp_path / "run"
    assert main(["eval", "--data", str(small_dataset), "--estimator", EXAMPLE, "--opt", "push_back=0.5",
                 "--max-images", "3", "--no-vsd", "--quiet", "--out", str(out)]) == 0
    metrics = json.loads((out / "metrics.json").read_text())
    assert metrics["num_failures"] == 0 and metrics["overall"]["num_estimates"] == metrics["overall"]["num_targets"]
    assert metrics["overall"]["median_te_m"] < 0.05  # the depth centroid finds the objects within a few centimetres
    assert main(["eval", "--data", str(small_dataset), "--estimator", EXAMPLE, "--opt", "push_bak=1",
                 "--out", str(tmp_path / "bad"), "--quiet"]) == 2
    assert "valid options: push_back=0.5, min_points=10" in capsys.readouterr().err


def test_example_estimator_runs_in_grasp_by_file_path(tmp_path):
    from simtest.cli import main

    out = tmp_path / "grasp"
    assert main(["grasp", "--estimator", EXAMPLE, "--episodes", "1", "--target", "box_1", "--width", "96",
                 "--out", str(out), "--quiet"]) == 0
    (row,) = _csv(out / "episodes.csv")
    assert row["reason"] not in ("estimator_error", "estimator_timeout", "no_estimate"), row
    assert float(row["te"]) < 0.05 and float(row["re_sym_deg"]) <= float(row["re_raw_deg"]) + 1e-9


# --- loading --------------------------------------------------------------------------------------------------
_PLUGIN = """
import numpy as np
from simtest.estimators import PoseEstimate

class Fixed:
    def __init__(self, depth: float = 0.5):
        self.depth = depth

    def estimate(self, observation):
        return [PoseEstimate(obj_id=o, R=np.eye(3), t=[0.0, 0.0, self.depth]) for o in observation.target_obj_ids]

def helper(message):
    raise ValueError(message)

class Raises:
    def estimate(self, observation):
        helper("no model for this object")
"""


def _write_plugin(folder: Path, name: str = "myplugin_est.py") -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    path = folder / name
    path.write_text(textwrap.dedent(_PLUGIN))
    return path


def test_load_from_a_relative_file_path(tmp_path, monkeypatch):
    _write_plugin(tmp_path / "plugins")
    monkeypatch.chdir(tmp_path)
    est = load_estimator("plugins/myplugin_est.py:Fixed", depth=0.7)
    assert type(est).__name__ == "Fixed" and est.depth == 0.7
    again = load_estimator("./plugins/myplugin_est.py:Fixed")
    assert type(again) is type(est)  # the file is imported once
    with pytest.raises(ConfigError, match=r"depth = 'x' has the wrong type; expected float .*valid options: "
                                          r"depth=0.5"):
        load_estimator("plugins/myplugin_est.py:Fixed", depth="x")
    with pytest.raises(ConfigError, match=r"has no attribute 'Fixd'; its classes and functions: Fixed, Raises, "
                                          r"helper$"):
        load_estimator("plugins/myplugin_est.py:Fixd")
    with pytest.raises(ConfigError, match=r"file not found: .*plugins/nothere.py"):
        load_estimator("plugins/nothere.py:Fixed")
    with pytest.raises(ConfigError, match=r"give the class or function too: plugins/myplugin_est.py:MyEstimator"):
        load_estimator("plugins/myplugin_est.py")
    (tmp_path / "plugins" / "broken.py").write_text("x = 1\nraise RuntimeError('needs a GPU')\n")
    with pytest.raises(ConfigError, match=r"importing .*broken.py raised RuntimeError: needs a GPU"):
        load_estimator("plugins/broken.py:Fixed")


def test_module_not_found_says_how_to_fix_it():
    with pytest.raises(ConfigError) as info:
        load_estimator("not_a_module_xyz:MyEstimator")
    assert ("No module named 'not_a_module_xyz': is it on PYTHONPATH" in str(info.value)
            and "or pass a file path: path/to/not_a_module_xyz.py:MyEstimator" in str(info.value))


def test_installed_entry_point_registers_an_estimator_by_name(tmp_path, monkeypatch):
    site = tmp_path / "site"
    _write_plugin(site, "epdemo_est.py")
    dist = site / "epdemo-0.1.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: epdemo\nVersion: 0.1\n")
    (dist / "entry_points.txt").write_text("[simtest.estimators]\nepdemo-fixed = epdemo_est:Fixed\n"
                                           "epdemo-broken = epdemo_missing:Nope\n")
    monkeypatch.syspath_prepend(str(site))
    assert {"epdemo-fixed", "epdemo-broken"} <= set(installed_estimators())
    est = load_estimator("epdemo-fixed", depth=0.4)
    assert type(est).__name__ == "Fixed" and est.depth == 0.4
    with pytest.raises(ConfigError, match=r"unknown estimator 'epdemo-fixd'; built-in: .*oracle.*; installed: "
                                          r"epdemo-broken, epdemo-fixed"):
        load_estimator("epdemo-fixd")
    with pytest.raises(ConfigError, match=r"entry point 'epdemo_missing:Nope' .*package 'epdemo'.* failed to load: "
                                          r"ModuleNotFoundError"):
        load_estimator("epdemo-broken")


# --- failures -------------------------------------------------------------------------------------------------
def test_always_raising_estimator_exits_1_with_its_traceback_in_failures_csv(small_dataset, tmp_path, capsys):
    from simtest.cli import main

    plugin = _write_plugin(tmp_path / "plugins")
    out = tmp_path / "run"
    assert main(["eval", "--data", str(small_dataset), "--estimator", f"{plugin}:Raises", "--max-images", "2",
                 "--no-vsd", "--quiet", "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("simtest eval: error: the estimator failed on 2 of 2 images (exception 2); first: "
                              "ValueError: no model for this object; see ")
    rows = _csv(out / "failures.csv")
    assert [(r["kind"], r["exception_type"]) for r in rows] == [("exception", "ValueError")] * 2
    tb = rows[0]["traceback"]
    assert f"{plugin}:" in tb and "in estimate: helper(" in tb and tb.endswith(
        "in helper: raise ValueError(message)") and "\n" not in tb


def test_fail_fast_stops_at_the_first_failure_with_the_traceback(small_dataset, tmp_path, capsys):
    from simtest.cli import main
    from simtest.evaluation.run import evaluate

    plugin = _write_plugin(tmp_path / "plugins")
    out = tmp_path / "run"
    assert main(["eval", "--data", str(small_dataset), "--estimator", f"{plugin}:Raises", "--fail-fast",
                 "--no-vsd", "--quiet", "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert "estimator failed (--fail-fast): Raises failed on scene 0 image 0 (exception): ValueError" in err
    assert "Traceback (most recent call last)" in err and 'raise ValueError(message)' in err
    assert not (out / "results.csv").exists()
    with pytest.raises(EstimatorError, match="invalid-estimate"):
        evaluate(small_dataset, lambda obs: [object()], fail_fast=True, progress=False, vsd=False)


def test_grasp_records_tracebacks_and_exits_1_when_every_episode_failed(tmp_path, capsys):
    from simtest.cli import main

    plugin = _write_plugin(tmp_path / "plugins")
    out = tmp_path / "run"
    args = ["grasp", "--estimator", f"{plugin}:Raises", "--target", "box_1", "--width", "64", "--quiet"]
    assert main([*args, "--episodes", "2", "--out", str(out)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1].startswith("simtest grasp: error: the estimator failed in 2 of 2 episodes (estimator_error 2); "
                              "first: ValueError: no model for this object")
    rows = _csv(out / "episodes.csv")
    assert [r["reason"] for r in rows] == ["estimator_error"] * 2
    assert rows[0]["traceback"].endswith("in helper: raise ValueError(message)")
    assert main([*args, "--episodes", "3", "--fail-fast", "--out", str(tmp_path / "ff")]) == 1
    err = capsys.readouterr().err
    assert "failed in episode 0" in err and "Traceback (most recent call last)" in err
    assert not (tmp_path / "ff" / "episodes.csv").exists()


def test_names_moved_out_of_base_still_import_with_a_deprecation_warning():
    import simtest.estimators.base as base
    from simtest.estimators import options, registry

    for name, module in base.MOVED.items():
        with pytest.warns(DeprecationWarning, match=rf"simtest\.estimators\.base\.{name} moved to {module}"):
            value = getattr(base, name)
        assert value is getattr(options if module.endswith("options") else registry, name)
    with pytest.raises(AttributeError, match="no attribute 'nope'"):
        base.nope


def test_model_clouds_are_cached_by_the_exact_mesh_not_the_rounded_hash():
    """A model read back from a dataset's PLY shares the rounded ``mesh_hash`` with its in-memory original while
    its vertices differ in the last bits; each must get its own cloud, so an ICP result never depends on which
    models the process met before (one worker vs two)."""
    import dataclasses

    import trimesh

    from simtest.estimators.icp import model_cloud
    from simtest.objects import load_object_set

    obj = load_object_set("builtin-small").by_name("can_0")
    nudged = trimesh.Trimesh(np.asarray(obj.vertices) * (1.0 + 1e-12), np.asarray(obj.faces), process=False)
    twin = dataclasses.replace(obj, mesh=nudged)
    assert twin.mesh_hash == obj.mesh_hash and not np.array_equal(twin.vertices, obj.vertices)
    a, b = model_cloud(obj, 300), model_cloud(twin, 300)
    assert a is not b and np.array_equal(b.points, twin.surface_cloud(300)[0])
    assert model_cloud(twin, 300) is b  # and still cached
