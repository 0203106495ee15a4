"""The ``grasp_tolerance`` metric of ``simtest eval``: an estimate is grasp-ready when its error lies within the
tolerance map on every axis; the metric reads exactly the limits of the map it is given."""

from __future__ import annotations

import json

import numpy as np
import pytest

from simtest.cli import main
from simtest.errors import ConfigError
from simtest.estimators.oracle import axis_angle_matrix
from simtest.evaluation.run import evaluate
from simtest.io.files import write_csv
from simtest.metrics.tolerance import ToleranceMap, error_components, largest_tolerated, read_tolerance_map

COLUMNS = ["object", "obj_id", "axis", "unit", "magnitude", "successes", "episodes", "symmetry"]
OBJ_IDS = (1, 7, 13, 22)  # builtin-small


def _map_rows(t_x_limit: float) -> list[dict]:
    """A map where t_x holds up to ``t_x_limit`` mm (10/10), fails beyond (2/10); other axes hold to 50."""
    rows = []
    for obj_id in OBJ_IDS:
        for axis in ("t_x", "t_y", "t_z", "t_ray", "r_x", "r_y", "r_z"):
            grid = [(0.0, 10), (t_x_limit, 10), (t_x_limit + 10, 2)] if axis == "t_x" else [(0.0, 10), (50.0, 10)]
            sym = "continuous" if (obj_id, axis) == (1, "r_z") else ""
            rows += [{"object": f"o{obj_id}", "obj_id": obj_id, "axis": axis, "unit": "mm", "magnitude": m,
                      "successes": k, "episodes": 10, "symmetry": sym} for m, k in grid]
    return rows


def test_error_components_split_the_error_along_the_axes():
    R_g = axis_angle_matrix(np.array([0.6, 0.0, 0.8]), 1.1)
    t_g = np.array([0.05, 0.02, 0.7])
    c = error_components(R_g @ axis_angle_matrix(np.array([1.0, 0, 0]), np.radians(30)), t_g + 0.012 * R_g[:, 1],
                         R_g, t_g)
    assert c["r_x"] == pytest.approx(30.0) and c["r_y"] == pytest.approx(0.0, abs=1e-9)
    assert c["t_y"] == pytest.approx(12.0) and c["t_x"] == pytest.approx(0.0, abs=1e-9)
    assert c["t_ray"] == pytest.approx(abs(12.0 * R_g[:, 1] @ t_g / np.linalg.norm(t_g)))
    # About a symmetry: measured from the nearest symmetric ground truth (a 180 degree turn about z).
    flip = np.diag([-1.0, -1.0, 1.0, 1.0])
    c = error_components(R_g @ flip[:3, :3], t_g, R_g, t_g, np.stack([np.eye(4), flip]))
    assert max(c.values()) == pytest.approx(0.0, abs=1e-6)


def test_map_limits_are_the_largest_tolerated_errors():
    m = ToleranceMap.from_rows(_map_rows(10.0))
    assert m.limits[7]["t_x"] == largest_tolerated([0, 10, 20], [10, 10, 2], [10, 10, 10]).tolerated == 10.0
    assert m.limits[1]["r_z"] == float("inf") and m.limits[7]["r_z"] == 50.0
    assert m.allows(7, {"t_x": 9.99, "r_z": 50.0}) and not m.allows(7, {"t_x": 10.5})
    assert m.allows(99, {"t_x": 0.0}) is None  # not in the map
    with pytest.raises(ValueError, match="unknown axis"):
        ToleranceMap.from_rows([{**_map_rows(10.0)[0], "axis": "yaw"}])


@pytest.mark.parametrize("error_mm, expected", [(8.0, 1.0), (12.0, 0.0)])
def test_eval_grasp_tolerance_equals_the_map(small_dataset, tmp_path, error_mm, expected):
    path = tmp_path / "tolerance.csv"
    write_csv(path, _map_rows(10.0), COLUMNS)
    rep = evaluate(small_dataset, "oracle", estimator_options={"error_axis": "t_x", "error": error_mm,
                                                               "error_sign": "+"},
                   progress=False, vsd=False, grasp_tolerance=path)
    assert rep.overall["grasp_tolerance"] == expected
    assert rep.overall["num_grasp_targets"] == rep.overall["num_targets"] == rep.overall["num_matched"]
    assert all(r["grasp_ready"] == bool(expected) for r in rep.errors)
    assert all(m["grasp_tolerance"] == expected for m in rep.per_object.values())


def test_cli_scores_a_results_file_for_grasp_readiness(small_dataset, tmp_path, capsys):
    path = tmp_path / "tolerance.csv"
    write_csv(path, _map_rows(10.0), COLUMNS)
    run = tmp_path / "run"
    assert main(["eval", "--data", str(small_dataset), "--estimator", "oracle", "--opt", "error_axis=t_x",
                 "--opt", "error=12", "--opt", "error_sign=+", "--no-vsd", "--out", str(run), "--quiet"]) == 0
    write_csv(path, _map_rows(20.0), COLUMNS)  # a looser map: the same estimates are now grasp-ready
    assert main(["eval", "--results", str(run / "results.csv"), "--data", str(small_dataset), "--no-vsd",
                 "--grasp-tolerance", str(path), "--out", str(tmp_path / "score"), "--quiet"]) == 0
    metrics = json.loads((tmp_path / "score" / "metrics.json").read_text())
    assert metrics["overall"]["grasp_tolerance"] == 1.0
    assert "Grasp-ready" in capsys.readouterr().out
    # --metrics picks the terminal's columns by registered name; the files keep every metric
    assert main(["eval", "--results", str(run / "results.csv"), "--data", str(small_dataset), "--no-vsd",
                 "--grasp-tolerance", str(path), "--metrics", "add_s_or_add_01d,grasp_tolerance",
                 "--out", str(tmp_path / "score2"), "--quiet"]) == 0
    out = capsys.readouterr().out
    assert "Grasp-ready" in out and "ADD(-S)-0.1d" in out and "AR_MSSD" not in out
    assert "ar_mssd" in json.loads((tmp_path / "score2" / "metrics.json").read_text())["overall"]
    assert main(["eval", "--results", str(run / "results.csv"), "--data", str(small_dataset), "--metrics",
                 "grasp_tolerance", "--out", str(tmp_path / "never")]) == 2
    assert "--grasp-tolerance" in capsys.readouterr().err and not (tmp_path / "never").exists()
    assert main(["eval", "--results", str(run / "results.csv"), "--data", str(small_dataset), "--metrics",
                 "add,no_such", "--out", str(tmp_path / "never")]) == 2
    assert "'no_such'" in capsys.readouterr().err
    with pytest.raises(ConfigError, match="not a readable tolerance.csv"):
        read_tolerance_map(tmp_path / "missing.csv")
