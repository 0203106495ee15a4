"""The detection task (``evaluate(..., task="detection")``): the estimator is told no target ids or counts,
estimators that need them are refused, the oracle's detection mode drives the AP path end to end, generate
writes both BOP target files, a many-class tree gets a per-category classification table, and localization
outputs are unchanged."""

from __future__ import annotations

import json

import numpy as np
import pytest

from simtest.errors import ConfigError
from simtest.estimators.base import PoseEstimate
from simtest.evaluation.run import evaluate, score_results


class Spy:
    """Records what it is shown; returns nothing."""

    def __init__(self):
        self.seen = []

    def estimate(self, obs):
        self.seen.append((obs.target_obj_ids, obs.masks, obs.boxes, obs.gt_poses, obs.gt_obj_ids))
        return []


class NeedsTargets:
    needs_targets = True

    def estimate(self, obs):
        return []


def test_estimator_never_sees_targets_in_detection(small_dataset):
    spy = Spy()
    evaluate(small_dataset, spy, task="detection", vsd=False, progress=False)
    assert spy.seen and all(s == (None,) * 5 for s in spy.seen)
    spy = Spy()
    evaluate(small_dataset, spy, vsd=False, progress=False)  # localization tells the ids
    assert all(s[0] is not None and s[1] is None for s in spy.seen)


@pytest.mark.parametrize("estimator, reason", [("icp", "needs_gt_masks"), ("track-icp", "needs_gt_init"),
                                               (NeedsTargets(), "needs_targets = True")])
def test_estimators_that_need_targets_are_refused(small_dataset, estimator, reason):
    with pytest.raises(ConfigError, match=f"detection task.*{reason}"):
        evaluate(small_dataset, estimator, task="detection", vsd=False, progress=False)


def test_unknown_task_is_refused(small_dataset):
    with pytest.raises(ConfigError, match="task must be one of localization, detection"):
        evaluate(small_dataset, "oracle", task="segmentation", progress=False)


def test_perfect_oracle_detects_everything(small_dataset, tmp_path):
    rep = evaluate(small_dataset, "oracle", task="detection", vsd=False, progress=False, out_dir=tmp_path)
    assert rep.overall["ap"] == rep.overall["ap_mssd"] == rep.overall["ap_mspd"] == 1.0
    assert rep.overall["cls_acc"] == rep.overall["cls_acc_pi_18"] == 1.0
    md = (tmp_path / "metrics.md").read_text()
    assert "| AP [%] | AP_MSSD [%] | AP_MSPD [%]" in md and "Detection task" in md
    saved = json.loads((tmp_path / "metrics.json").read_text())
    assert saved["settings"]["task"] == "detection" and "ap_mssd" in saved["definitions"]
    assert (tmp_path / "classification.csv").read_text().startswith("scene_id,im_id,gt_id,obj_id,category")


def test_oracle_misses_duplicates_and_false_positives_lower_the_ap(small_dataset, tmp_path):
    opts = {"drop_rate": 0.3, "duplicates": 0.5, "false_positives": 2.0, "random_scores": True, "seed": 3}
    rep = evaluate(small_dataset, "oracle", task="detection", vsd=False, progress=False, out_dir=tmp_path,
                   estimator_options=opts)
    assert len(rep.estimates) > rep.overall["num_targets"]  # duplicates and false positives are there
    assert 0.0 < rep.overall["ap"] < 0.9 and rep.overall["cls_acc"] < 1.0
    again = score_results(tmp_path / "results.csv", small_dataset, vsd=False, progress=False, task="detection")
    for k in ("ap", "ap_mssd", "ap_mspd", "ap_mssd_mm", "cls_acc", "cls_acc_pi_6"):
        assert again.overall[k] == pytest.approx(rep.overall[k], abs=1e-12), k
    # the same seed without the extras gives the same estimates of the targets
    base = evaluate(small_dataset, "oracle", task="detection", vsd=False, progress=False,
                    estimator_options={"drop_rate": 0.3, "seed": 3})
    key = {(r.scene_id, r.im_id, r.obj_id, tuple(np.round(r.t, 9))) for r in rep.estimates}
    assert all((r.scene_id, r.im_id, r.obj_id, tuple(np.round(r.t, 9))) in key for r in base.estimates)


def test_generate_writes_both_target_files(small_dataset):
    from simtest.io.bop import read_scene, scene_dirs

    t19 = json.loads((small_dataset / "test_targets_bop19.json").read_text())
    t24 = json.loads((small_dataset / "test_targets_bop24.json").read_text())
    images = [(int(d.name), im) for d in scene_dirs(small_dataset / "train_pbr") for im in sorted(read_scene(d))]
    assert [(t["scene_id"], t["im_id"]) for t in t24] == images and all(set(t) == {"scene_id", "im_id"} for t in t24)
    assert all(set(t) == {"scene_id", "im_id", "obj_id", "inst_count"} and t["inst_count"] >= 1 for t in t19)
    n = sum(1 for d in scene_dirs(small_dataset / "train_pbr") for im in read_scene(d).values()
            for g in im["gt"] if g.visib_fract >= 0.1)
    assert sum(t["inst_count"] for t in t19) == n


def test_localization_outputs_carry_nothing_of_detection(small_dataset, tmp_path):
    rep = evaluate(small_dataset, "oracle", vsd=False, progress=False, out_dir=tmp_path)
    saved = json.loads((tmp_path / "metrics.json").read_text())
    assert "task" not in saved["settings"] and "ap" not in saved["definitions"] and "ap" not in rep.overall
    assert "AP [%]" not in (tmp_path / "metrics.md").read_text() and not (tmp_path / "classification.csv").exists()


def test_cli_detection(small_dataset, tmp_path, capsys):
    from simtest.cli import main

    assert main(["eval", "--data", str(small_dataset), "--estimator", "oracle", "--task", "detection",
                 "--no-vsd", "--quiet", "--out", str(tmp_path / "o")]) == 0
    assert "AP_MSSD" in capsys.readouterr().out
    assert main(["eval", "--data", str(small_dataset), "--estimator", "oracle", "--task", "detection",
                 "--targets", "gt-masks", "--quiet", "--out", str(tmp_path / "p")]) != 0
    assert "--targets applies to --task localization" in capsys.readouterr().err


# ---------------------------------------------------------------------------------------------------------
# A many-class tree: per-category classification
class Relabel:
    """Ground-truth poses, objects renamed by ``swap`` (``{obj_id: answered obj_id}``)."""

    needs_gt = True
    needs_targets = False

    def __init__(self, swap):
        self.swap = swap

    def estimate(self, obs):
        return [PoseEstimate(self.swap.get(o, o), R, t, score=1.0) for o, (R, t) in zip(obs.gt_obj_ids, obs.gt_poses)]


@pytest.fixture(scope="module")
def library_dataset(tmp_path_factory):
    from simtest.benchmarks.objects import write_mesh_tree
    from simtest.generators.config import GenerateConfig
    from simtest.generators.pipeline import generate

    base = tmp_path_factory.mktemp("libdet")
    tree = write_mesh_tree(base / "meshes", 150, 30, seed=3)
    mp = pytest.MonkeyPatch()
    mp.setenv("SIMTEST_CACHE", str(base / "cache"))
    cfg = GenerateConfig().replace(**{
        "objects": str(tree), "scenes": 1, "frames_per_scene": 2, "camera.width": 160, "camera.height": 120,
        "scene.objects_per_scene": [6, 6], "scene.allow_repeats": False, "scene.distractors": [0, 0],
        "seed": 11})
    try:
        generate(cfg, base / "ds", progress=False)
    finally:
        mp.undo()
    return base / "ds"


def test_category_table_on_a_many_class_tree(library_dataset, tmp_path):
    from simtest.io.bop import read_scene, scene_dirs
    from simtest.objects.loaders import load_dataset_objects

    objects = load_dataset_objects(library_dataset)
    used = sorted({g.obj_id for d in scene_dirs(library_dataset / "train_pbr") for im in read_scene(d).values()
                   for g in im["gt"] if g.visib_fract >= 0.1})
    cat = {e.obj_id: e.category for e in objects.entries}
    cats = sorted({cat[o] for o in used})
    assert len(cats) >= 3
    # the dataset's models are the objects its scenes use: answer cats[0]'s objects as an object of cats[1]
    other = next(o for o in used if cat[o] == cats[1])
    rep = evaluate(library_dataset, Relabel({o: other for o in used if cat[o] == cats[0]}), task="detection",
                   vsd=False, progress=False, out_dir=tmp_path)
    per = rep.per_category
    assert set(per) == set(cats)
    assert per[cats[0]]["cls_acc"] == 0.0 and per[cats[0]]["cls_median_re_deg"] == 180.0
    assert all(per[c]["cls_acc"] == 1.0 and per[c]["cls_acc_pi_18"] == 1.0 for c in cats[1:])
    n = sum(m["num_targets"] for m in per.values())
    assert rep.overall["cls_acc"] == pytest.approx(1 - per[cats[0]]["num_targets"] / n)
    md = (tmp_path / "metrics.md").read_text()
    assert "#### Per category" in md and "| Cls [%] | Cls Acc@π/6 [%] | Cls Acc@π/18 [%] | Cls MedErr [deg]" in md
    saved = json.loads((tmp_path / "metrics.json").read_text())["per_category"]
    assert saved[cats[0]]["cls_acc"] == 0.0 and saved[cats[2]]["ap"] == 1.0 and saved[cats[1]]["ap"] < 1.0  # FPs


def test_a_detection_sweep_fills_its_tables_and_report(small_dataset, tmp_path):
    """A sweep with ``task = "detection"``: the oracle's detection mode over a clean and an occluded cell; the
    BOP24 columns reach summary.csv, tables.md and report.html."""
    import csv

    from simtest.cli import main

    config = tmp_path / "sweep.toml"
    config.write_text(f'seed = 0\ntask = "detection"\nmetrics = ["ap", "ap_mssd", "ap_mspd", "cls_acc"]\n'
                      f'[[estimators]]\nname = "oracle-det"\nestimator = "oracle"\n'
                      f'options = {{ false_positives = 1, drop_rate = 0.2 }}\n'
                      f'[dataset]\npath = "{small_dataset}"\n[factors]\nocclusion = ["L2"]\ncorruptions = []\n'
                      f'depth_noise = []\n[grasp]\nepisodes = 0\n')
    assert main(["sweep", "--quiet", str(config), "--out", str(tmp_path / "sweep")]) == 0
    rows = list(csv.DictReader((tmp_path / "sweep" / "summary.csv").open()))
    metrics = {r["metric"] for r in rows}
    assert {"ap", "ap_mssd", "ap_mspd", "cls_acc"} <= metrics, metrics
    aps = [float(r["value"]) for r in rows if r["metric"] == "ap"]
    assert len(aps) == 2 and all(0.0 < v < 1.0 for v in aps)  # misses and false positives lower it
    assert "AP_MSSD" in (tmp_path / "sweep" / "tables.md").read_text()
    assert "AP_MSSD" in (tmp_path / "sweep" / "report.html").read_text()
