"""`simtest bench generate --profiles ... --json` and `simtest bench check`: the pbr frame by stage, the table as
JSON, and fresh / recorded ratios (real generation runs on small images)."""

from __future__ import annotations

import importlib.util
import json

import pytest

from simtest.benchmarks.check import RECORDED, check_table, compare, read_record
from simtest.benchmarks.machine import cpu_name
from simtest.cli import main
from simtest.errors import ConfigError

if importlib.util.find_spec("mitsuba") is None or importlib.util.find_spec("pyoidn") is None:
    pytest.skip("the pbr extra is not installed", allow_module_level=True)


def test_profiles_json_and_the_check_against_it(tmp_path, capsys):
    """A pbr run writes its table (with the frame by stage) as JSON; checked against itself every ratio is 1;
    against a record twice as fast the check fails (exit status 1) and says which row is slower."""
    out = tmp_path / "bench.json"
    assert main(["bench", "generate", "--profiles", "pbr", "--sizes", "64x48", "--scenes", "1", "--views", "2",
                 "--objects", "builtin-small", "--objects-per-scene", "2", "--no-workers", "--json", str(out)]) == 0
    text = capsys.readouterr().out
    assert "pbr frame by stage" in text and "| trace |" in text
    rec = read_record(out)
    (row,) = rec["rows"]
    assert row["profile"] == "pbr" and (row["width"], row["height"]) == (64, 48) and row["spp"] == 12
    assert set(row["stages"]) == {"scene", "sensor", "trace", "guides", "denoise", "image", "rest"}
    assert row["stages"]["trace"] > 0 and row["scene_loads"] == 1
    assert sum(row["stages"].values()) == pytest.approx(row["wall"], rel=0.02, abs=2e-3)
    assert rec["machine"]["cores"] >= 1 and len(rec["machine"]["load_average_1_5_15"]) == 3
    assert rec["machine"]["cpu"] == cpu_name()
    assert rec["command"].startswith("simtest bench generate --profiles pbr")

    assert main(["bench", "check", "--recorded", str(out), "--fresh", str(out)]) == 0
    text = capsys.readouterr().out
    assert "| pbr | 64x48 |" in text and "| 1.00 | 1.00 | yes |" in text
    assert f"processor: recorded {cpu_name()}, fresh {cpu_name()}" in text and "NOTE" not in text

    fast = dict(rec, rows=[dict(row, wall=row["wall"] / 2, cpu=row["cpu"] / 2)])
    faster = tmp_path / "faster.json"
    faster.write_text(json.dumps(fast))
    assert main(["bench", "check", "--recorded", str(faster), "--fresh", str(out)]) == 1
    assert "| 2.00 | 2.00 | NO: slower |" in capsys.readouterr().out
    assert main(["bench", "check", "--recorded", str(faster), "--fresh", str(out), "--tolerance", "2.5"]) == 0


def test_compare_ratios_missing_rows_and_bad_arguments(tmp_path):
    """Ratios are fresh / recorded of the measure asked; a recorded row the fresh run lacks has no verdict; a
    bad measure, tolerance or file is named."""
    row = {"profile": "pbr", "width": 320, "height": 240, "wall": 0.5, "cpu": 1.0}
    recorded = {"kind": "profiles", "rows": [row, dict(row, width=640, height=480)]}
    fresh = {"kind": "profiles", "rows": [dict(row, wall=0.6, cpu=0.9)]}
    a, b = compare(recorded, fresh, tolerance=1.1, measure="wall")
    assert a.wall_ratio == pytest.approx(1.2) and a.cpu_ratio == pytest.approx(0.9) and a.ok is False
    assert compare(recorded, fresh, tolerance=1.1)[0].ok is True  # cpu by default
    assert b.fresh_wall is None and b.ok is None and b.wall_ratio is None
    with pytest.raises(ConfigError, match="allowed: wall, cpu"):
        compare(recorded, fresh, measure="fps")
    with pytest.raises(ConfigError, match="tolerance must be > 0, got 0"):
        compare(recorded, fresh, tolerance=0)
    with pytest.raises(ConfigError, match="does not exist"):
        read_record(tmp_path / "none.json")
    (tmp_path / "g.json").write_text(json.dumps({"kind": "generate"}))
    with pytest.raises(ConfigError, match="kind 'generate'"):
        read_record(tmp_path / "g.json")


def test_the_recorded_figures_are_a_profiles_table_of_the_pbr_profile():
    rec = read_record(RECORDED)
    sizes = {(r["width"], r["height"]) for r in rec["rows"] if r["profile"] == "pbr"}
    assert {(320, 240), (640, 480)} <= sizes
    assert all(r["wall"] > 0 and r["cpu"] > 0 for r in rec["rows"])


def test_the_processor_is_read_and_a_change_of_it_is_said(tmp_path):
    """``cpu_name`` reads the first processor's model name and family / model numbers from a cpuinfo file; the
    check's table names both runs' processors and warns when they differ (or one is not recorded)."""
    info = tmp_path / "cpuinfo"
    info.write_text("processor\t: 0\nvendor_id\t: AuthenticAMD\ncpu family\t: 26\nmodel\t\t: 2\n"
                    "model name\t: AMD EPYC\n\nprocessor\t: 1\nmodel name\t: other\n")
    assert cpu_name(info) == "AMD EPYC (family 26, model 2)"
    assert cpu_name(tmp_path / "absent") != ""
    row = {"profile": "pbr", "width": 320, "height": 240, "wall": 0.5, "cpu": 1.0}
    old = {"kind": "profiles", "rows": [row], "machine": {"cpu": "AMD EPYC (family 25, model 1)"}}
    new = {"kind": "profiles", "rows": [row], "machine": {"cpu": "AMD EPYC (family 26, model 2)"}}
    text = check_table(compare(old, new), old, new, 1.3, "cpu")
    assert "processor: recorded AMD EPYC (family 25, model 1), fresh AMD EPYC (family 26, model 2)" in text
    assert "NOTE: the runs are not known to be on the same processor" in text
    assert "NOTE" not in check_table(compare(new, new), new, new, 1.3, "cpu")
    bare = {"kind": "profiles", "rows": [row]}
    assert "recorded not recorded" in check_table(compare(bare, new), bare, new, 1.3, "cpu")
