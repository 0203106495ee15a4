"""Sweeps end to end: outputs, resume by cell, the HTML report, and config errors."""

from __future__ import annotations

import json
from html.parser import HTMLParser

import pytest

from simtest.errors import ConfigError, DatasetError
from simtest.sweeps.grid import SweepConfig, run_sweep

TINY = {
    "seed": 0,
    "estimators": [{"name": "oracle", "estimator": "oracle", "options": {"rot_noise_deg": 2.0}}],
    "dataset": {"generate": {"objects": "builtin-small", "scenes": 1, "frames_per_scene": 2,
                             "camera": {"width": 96, "height": 72}}},
    "factors": {"corruptions": ["fog"], "severities": [4]},  # no occlusion or depth factor: no such column
    "grasp": {"episodes": 1, "width": 96, "height": 72},
}


class _Figures(HTMLParser):
    def __init__(self) -> None:
        super().__init__()
        self.figures: list[str] = []
        self.images: list[str] = []
        self.tables = 0

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "figure" and "id" in a:
            self.figures.append(a["id"])
        if tag == "img":
            self.images.append(a.get("src", ""))
        if tag == "table":
            self.tables += 1


@pytest.fixture(scope="module")
def tiny_sweep(tmp_path_factory):
    cfg = SweepConfig.from_dict(TINY)
    out = tmp_path_factory.mktemp("sweep") / "s"
    rep = run_sweep(cfg, out, progress=False)
    return cfg, out, rep


def test_tiny_sweep_writes_every_output(tiny_sweep):
    cfg, out, rep = tiny_sweep
    # 2 conditions (clean, fog-4) x 1 estimator x (pose, grasp)
    assert sorted(rep.cells_run) == sorted(["oracle/clean/pose", "oracle/clean/grasp", "oracle/fog-4/pose",
                                            "oracle/fog-4/grasp"])
    for name in ("results.csv", "summary.csv", "tables.md", "report.html"):
        assert (out / name).is_file()
    tables = (out / "tables.md").read_text()
    assert "| estimator | L0 (n=" in tables and " | fog-4 (n=" in tables and "Grasp success" in tables
    assert "realsense" not in tables and "| L1" not in tables  # exactly the requested conditions
    results = (out / "results.csv").read_text().splitlines()
    assert results[0].startswith("estimator,condition,factor")
    assert any(",pose," in r for r in results[1:]) and any(",grasp," in r for r in results[1:])


def test_report_html_parses_and_embeds_every_plot(tiny_sweep):
    cfg, out, _ = tiny_sweep
    p = _Figures()
    p.feed((out / "report.html").read_text())
    expected = {f"plot-{m}" for m in cfg.metrics} | {"plot-grasp-occlusion", "plot-error-vs-grasp"}
    assert expected <= set(p.figures)
    assert all(src.startswith("data:image/") for src in p.images)
    assert len(p.images) >= len(expected) + 2  # plots + one example image per condition
    assert p.tables >= len(cfg.metrics) + 1


def test_resume_skips_finished_cells(tiny_sweep):
    cfg, out, _ = tiny_sweep
    (out / "cells" / "oracle" / "fog-4" / "pose" / "cell.json").unlink()  # as if interrupted in that cell
    with pytest.raises(DatasetError, match="--resume"):
        run_sweep(cfg, out, progress=False)
    rep = run_sweep(cfg, out, resume=True, progress=False)
    assert rep.cells_run == ["oracle/fog-4/pose"]
    assert len(rep.cells_skipped) == 3
    other = SweepConfig.from_dict({**TINY, "seed": 1})
    with pytest.raises(DatasetError, match="another config"):
        run_sweep(other, out, resume=True, progress=False)


@pytest.mark.parametrize("patch, message", [
    ({"factors": {"corruptions": ["fogg"]}}, r"factors\.corruptions = 'fogg' is invalid; allowed: .*fog"),
    ({"factors": {"occlusion": ["L4"]}}, r"factors\.occlusion = 'L4' is invalid"),
    ({"metrics": ["add"]}, r"metrics = 'add' is invalid; allowed: .*add_s_or_add_01d"),
    ({"estimators": [{"name": "x", "estimator": "nonesuch"}]}, r"estimators\[0\]\.estimator = 'nonesuch'"),
    ({"grasp": {"episodes": -1}}, r"grasp\.episodes = -1 is invalid; allowed: \[0, 100000\]"),
    ({"factor": {}}, r"unknown field\(s\) factor"),
])
def test_bad_sweep_config_names_key_and_allowed_values(patch, message):
    data = json.loads(json.dumps(TINY))
    for k, v in patch.items():
        data[k] = {**data[k], **v} if isinstance(v, dict) and isinstance(data.get(k), dict) else v
    with pytest.raises(ConfigError, match=message):
        SweepConfig.from_dict(data)


def test_demo_sweep_matches_the_shipped_config():
    from pathlib import Path

    from simtest.sweeps.grid import DEMO_SWEEP, load_sweep_config

    shipped = load_sweep_config(Path(__file__).parents[3] / "configs" / "sweep-demo.toml")
    assert shipped == SweepConfig.from_dict(DEMO_SWEEP)


def test_a_sweep_has_exactly_the_requested_conditions():
    from simtest.sweeps.grid import conditions_of

    base = {"estimators": [{"name": "o", "estimator": "oracle"}], "dataset": {"path": "data"}}
    assert [c.name for c in conditions_of(SweepConfig.from_dict(base))] == ["clean"]
    asked = SweepConfig.from_dict({**base, "factors": {"occlusion": ["L2"], "corruptions": ["fog"]}})
    assert [c.name for c in conditions_of(asked)] == ["clean", "L2", "fog-4"]  # no depth-realsense-d435


def test_sweep_help_names_only_options_it_takes(capsys):
    from simtest.cli import main

    with pytest.raises(SystemExit):
        main(["sweep", "--help"])
    text = capsys.readouterr().out
    assert "--workers" not in text and "the config's `workers`" in text


def test_report_tables_show_n_and_intervals(tiny_sweep):
    import csv
    import re

    from simtest.metrics.intervals import wilson_interval

    cfg, out, _ = tiny_sweep
    summary = list(csv.DictReader((out / "summary.csv").open()))
    results = list(csv.DictReader((out / "results.csv").open()))
    for r in summary:
        if r["kind"] == "pose" and r["metric"] in cfg.metrics:
            assert r["interval"] in ("wilson", "bootstrap"), r
            assert float(r["ci95_low"]) <= float(r["value"]) <= float(r["ci95_high"]), r
            targets = [t for t in results if t["kind"] == "pose" and t["condition"] == r["condition"]]
            assert int(r["n"]) == len(targets) > 0
        if r["metric"] == "add_s_or_add_01d":  # Wilson over the targets of results.csv
            hits = sum(t["matched"] == "1" and float(t["add_s_or_add_m"]) < 0.1 * float(t["diameter_m"])
                       for t in targets)
            assert (float(r["ci95_low"]), float(r["ci95_high"])) == pytest.approx(wilson_interval(hits, len(targets)))
    tables = (out / "tables.md").read_text()
    pose = re.compile(r"^\d+\.\d \[\d+\.\d, \d+\.\d\]$")
    grasp = re.compile(r"^\d+ \[\d+, \d+\]$")
    blocks = tables.split("### ")[1:]
    assert len(blocks) == len(cfg.metrics) + 1
    for block in blocks:
        rows = [line.strip("|").split("|") for line in block.splitlines() if line.startswith("| oracle")]
        head = next(line for line in block.splitlines() if line.startswith("| estimator"))
        assert re.findall(r"\(n=\d+\)", head) and len(re.findall(r"\(n=\d+\)", head)) == 2, head
        shape = grasp if block.startswith("Grasp") else pose
        assert rows and all(shape.match(c.strip()) for r in rows for c in r[1:]), block
    assert '<span class="ci">[' in (out / "report.html").read_text()


def test_a_flat_row_has_no_worst_condition(tiny_sweep):
    _, out, _ = tiny_sweep
    page = (out / "report.html").read_text()  # the oracle reads no image: fog changes nothing
    assert "no condition worse than clean beyond the 95 % intervals" in page and "worst under" not in page


def test_scores_differ_only_beyond_their_intervals():
    from simtest.sweeps.uncertainty import Interval, differs

    clean = (0.95, Interval(40, 0.83, 0.99, "wilson"))
    assert not differs((0.90, Interval(40, 0.77, 0.96, "wilson")), clean)
    assert differs((0.50, Interval(40, 0.35, 0.65, "wilson")), clean)
    assert not differs((0.95, Interval(40)), (0.95, Interval(40)))  # no interval: plain inequality
    assert differs((0.2, Interval(4)), (0.3, Interval(4)))


def test_fitted_fifty_percent_point_is_stated_only_within_the_data():
    import numpy as np

    from simtest.sweeps.plots import fifty_percent_note, fit_logistic, logistic_band

    def note(x, y):
        a, b = fit_logistic(x, y)
        return fifty_percent_note(a, b, x, y, logistic_band(x, y, np.linspace(x.min(), x.max(), 50))[2])

    x = np.linspace(0.0, 19.0, 40)
    few = (x < 18.2).astype(float)  # two failures, at the largest errors
    assert note(x, few).startswith("50 % point not estimated: 2 failure(s)")
    rising = np.where(x > 5, np.arange(40) % 4 != 0, 1.0).astype(float)  # 7 of 30 fail past 5 mm: fit 50 % ~28
    assert note(x, rising).startswith("50 % not reached within the data (0.0-19.0 mm)")
    x = np.linspace(0.0, 40.0, 200)
    text = note(x, (x + np.sin(x * 7) * 3 < 20).astype(float))
    assert text.startswith("50 % at 2") and "[" in text, text
