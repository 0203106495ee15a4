"""``simtest adapt``: the fitted sampler on a fixed results table, the written config reproducing its dataset,
and the loop at toy size (a real sweep, generation, training and evaluation)."""

from __future__ import annotations

import json
import tomllib

import numpy as np
import pytest

from simtest.cli import main
from simtest.generators.config import GenerateConfig, load_config
from simtest.generators.pipeline import generate
from simtest.sweeps.adapt_fit import FACTORS, adapted_config, adapted_mass, fit_factor, fit_sampler
from simtest.sweeps.adapt_targets import TargetResult

pytest.importorskip("torch")


def _table() -> list[TargetResult]:
    """A fixed results table: near cameras fail far more than far ones; object 7 fails most."""
    rows = []
    for k in range(120):
        near = k % 2 == 0
        failed = (k % 10 < 8) if near else (k % 10 == 1)
        rows.append(TargetResult("clean" if k % 3 else "fog-4", (1, 7, 13)[k % 3] if not failed else 7,
                                 0.2 + 0.7 * (k % 7) / 6, 0.5 if near else 0.85, 30.0 + k % 40, 0.0, failed))
    return rows


def test_more_failures_get_more_mass_and_no_bin_gets_nothing():
    mass = adapted_mass([30, 12, 0, 1], [40, 40, 40, 2])
    assert mass.sum() == pytest.approx(1.0)
    assert mass[0] > mass[1] > mass[2] > 0 and mass[3] > 0
    assert mass[2] == pytest.approx(0.25 / 4)  # an empty interval keeps the floor's share
    assert mass[3] < mass[1]  # 50 % of 2 targets (a wide interval) gets less than 30 % of 40: noise not chased
    assert adapted_mass([0, 0], [5, 5]).tolist() == [0.5, 0.5]
    fits = {f.factor.name: f for f in fit_sampler(_table(), GenerateConfig(), bins=4)}
    dist = fits["distance"].bins  # 0.45-0.9 m in four parts: 0.5 m in the first, 0.85 m in the last
    assert dist[0].failures > dist[3].failures and dist[0].mass > dist[3].mass > 0
    assert all(b.mass > 0 for f in fits.values() for b in f.bins)
    assert all(sum(b.mass for b in f.bins) == pytest.approx(1.0) for f in fits.values())
    obj = {b.label: b.mass for b in fits["object"].bins}
    assert obj["7"] == max(obj.values())
    with pytest.raises(ValueError, match="one failure flag per value"):
        fit_factor(FACTORS[3], [0.5], [True, False], (0.45, 0.9))


def test_the_written_config_reproduces_its_dataset(tmp_path, small_config):
    fits = fit_sampler(_table(), small_config, bins=3)
    cfg = adapted_config(small_config.replace(frames_per_scene=2), fits, images=2, seed=11)
    path = tmp_path / "adapted.toml"
    path.write_text(cfg.to_toml())
    back = load_config(path)
    assert back == cfg and back.shell.distance_weights and back.scene.object_weights["7"] > 1.0
    assert tomllib.loads(path.read_text())["occlusion"]["visib_band"] == [0.0, 1.0]
    for run in ("a", "b"):
        generate(back, tmp_path / run, progress=False)
    files = sorted(p.relative_to(tmp_path / "a") for p in (tmp_path / "a" / "train_pbr").rglob("*") if p.is_file())
    assert files
    for rel in files:
        assert (tmp_path / "a" / rel).read_bytes() == (tmp_path / "b" / rel).read_bytes(), rel


@pytest.mark.parametrize("estimator", ["segicp", "keypoints"])
def test_the_loop_runs_end_to_end(tmp_path, estimator):
    sweep_cfg = tmp_path / "sweep.toml"
    sweep_cfg.write_text(f'seed = 3\nmetrics = ["add_s_or_add_01d"]\n[[estimators]]\nname = "{estimator}"\n'
                         f'estimator = "{estimator}"\n[dataset.generate]\nobjects = "builtin-small"\nscenes = 1\n'
                         'frames_per_scene = 2\ncamera = { width = 160, height = 120 }\n[factors]\n'
                         'occlusion = ["L2"]\n')
    assert main(["sweep", str(sweep_cfg), "--out", str(tmp_path / "sweep"), "--quiet"]) == 0
    train = tmp_path / "train.toml"
    train.write_text("epochs = 1\nbatch_size = 2\nthreads = 1\naugment = []\n")
    out = tmp_path / "adapt"
    assert main(["adapt", "--sweep", str(tmp_path / "sweep"), "--out", str(out), "--images", "2",
                 "--train-config", str(train), "--quiet"]) == 0
    result = json.loads((out / "adapt.json").read_text())
    assert set(result["before"]) == {"clean", "L2"}
    for arm in ("control", "adapted"):
        assert result["arms"][arm]["images"] == 2
        assert set(result["arms"][arm]["conditions"]) == {"clean", "L2"}
        assert (out / "train" / arm / "model.pt").is_file()
        assert (out / "sweeps" / arm / "cells" / estimator / "L2" / "pose").is_dir()
    assert result["verdict"]["weakest_condition"] in ("clean", "L2")
    assert result["verdict"]["weakest_aimed_condition"] in ("clean", "L2")
    assert "| L2 |" in (out / "adapt.md").read_text() and (out / "mass.png").stat().st_size > 1000
    fit = json.loads((out / "fit.json").read_text())
    assert [f["factor"] for f in fit["factors"]] == [f.name for f in FACTORS]
    assert np.isclose(sum(b["mass"] for b in fit["factors"][0]["bins"]), 1.0)
    assert main(["adapt", "--sweep", str(tmp_path / "sweep"), "--out", str(tmp_path / "x"), "--images", "2",
                 "--estimator", "icp"]) == 2


def test_the_shipped_adapt_configs_load():
    from pathlib import Path

    from simtest.sweeps.adapt_loop import load_train_config
    from simtest.sweeps.grid import load_sweep_config

    root = Path(__file__).parents[3] / "configs"
    sweep = load_sweep_config(root / "sweep-adapt.toml")
    assert [e.estimator for e in sweep.estimators] == ["segicp", "keypoints"]
    train = load_train_config(root / "adapt-train.toml")
    assert train.data == () and train.augment == ("occlusion", "weather")


def test_the_verdict_names_the_weakest_condition_the_config_aims_at():
    from simtest.sweeps.adapt_loop import _verdict

    def score(ok, n):
        from simtest.metrics.intervals import wilson_interval
        return {"score": ok / n, "ci95": list(wilson_interval(ok, n)), "n": n}

    before = {"clean": score(80, 100), "L3": score(40, 100), "fog-4": score(10, 100)}
    control = {"clean": score(80, 100), "L3": score(40, 100), "fog-4": score(10, 100)}
    adapted = {"clean": score(79, 100), "L3": score(70, 100), "fog-4": score(11, 100)}
    v = _verdict(before, {"control": {"conditions": control}, "adapted": {"conditions": adapted}})
    assert v["weakest_condition"] == "fog-4" and not v["success"]
    assert v["weakest_aimed_condition"] == "L3" and v["aimed"]["adapted_above_control_interval"]
    assert np.isclose(v["aimed"]["adapted_minus_control"], 0.30)
    assert v["clean_within_control_interval"]
