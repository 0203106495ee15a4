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
    "factors": {"occlusion": [], "corruptions": ["fog"], "severities": [4], "depth_noise": []},
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
    assert "| estimator | L0 | fog-4 |" in tables and "Grasp success" in tables
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
