"""The evaluation runner, BOP results CSV I/O, score_results and the ``simtest eval`` command."""

from __future__ import annotations

import json
from types import SimpleNamespace

import numpy as np
import pytest

from simtest.errors import DatasetError
from simtest.estimators import PoseEstimate
from simtest.evaluation.run import evaluate, score_results
from simtest.io.bop_results import read_bop_results, write_bop_results
from simtest.metrics.bop19 import ResultRow


class Raising:
    def estimate(self, observation):
        if observation.im_id == 1:
            raise RuntimeError("boom")
        return []


class NaNPose:
    """Returns pose-like objects with NaN (a PoseEstimate refuses NaN at construction)."""

    def estimate(self, observation):
        return [SimpleNamespace(obj_id=o, R=np.eye(3), t=np.array([np.nan, 0.0, 1.0]))
                for o in observation.target_obj_ids]


def test_oracle_without_noise_scores_perfectly(small_dataset, tmp_path):
    rep = evaluate(small_dataset, "oracle", out_dir=tmp_path, progress=False)
    o = rep.overall
    assert o["num_targets"] > 10 and o["num_matched"] == o["num_targets"] and not rep.failures
    assert max(r["add"] for r in rep.errors) < 1e-9 and max(r["mssd"] for r in rep.errors) < 1e-9
    for key in ("add_s_or_add_01d", "adds_lt_2cm", "acc_pi_6", "acc_pi_18", "5deg2cm", "ar", "ar_vsd", "ar_mssd",
                "ar_mspd"):
        assert o[key] == 1.0, key
    assert o["auc_adds"] == pytest.approx(1.0) and o["median_re_deg"] < 1e-5
    for name in ("results.csv", "metrics.json", "errors.csv", "failures.csv", "metrics.md"):
        assert (tmp_path / name).is_file()
    table = (tmp_path / "metrics.md").read_text()
    assert "| **All** |" in table and "[deg]" in table and "[cm]" in table
    assert json.loads((tmp_path / "metrics.json").read_text())["overall"]["ar"] == 1.0


def test_oracle_noise_gives_expected_errors(small_dataset):
    rep = evaluate(small_dataset, "oracle", estimator_options={"rot_noise_deg": 5.0, "trans_noise_mm": 5.0,
                                                             "rot_noise_mode": "fixed"}, progress=False, vsd=False)
    for r in rep.errors:
        assert r["te"] == pytest.approx(0.005, abs=1e-9)
        assert r["re"] == pytest.approx(5.0, abs=1e-6)
        assert r["re_sym"] <= 5.0 + 1e-6
    assert rep.overall["5deg5cm"] < 1.0 and rep.overall["10deg2cm"] == 1.0
    assert np.isnan(rep.overall["ar_vsd"]) and 0.0 < rep.overall["ar"] < 1.0
    half = evaluate(small_dataset, "oracle", estimator_options={"rot_noise_deg": 5.0, "trans_noise_mm": 5.0},
                    progress=False, vsd=False)
    # Half-normal angle with sigma 5 deg: median 3.4 deg; Maxwell distance with sigma 5 mm: mean 8 mm.
    assert 1.5 < half.overall["median_re_deg"] < 6.0
    assert 0.004 < np.mean([r["te"] for r in half.errors]) < 0.012


def test_oracle_keypoint_noise_is_pnp_from_noisy_ground_truth_keypoints(small_dataset):
    def run(**opts):
        return evaluate(small_dataset, "oracle", estimator_options=opts, progress=False, vsd=False)

    exact = run(keypoint_noise_px=1e-6)  # PnP from exact keypoints gives the pose back
    assert exact.overall["num_matched"] == exact.overall["num_targets"]
    assert max(r["re"] for r in exact.errors) < 1e-3 and max(r["te"] for r in exact.errors) < 1e-5
    noisy, again = run(keypoint_noise_px=3.0, keypoints="fps"), run(keypoint_noise_px=3.0, keypoints="fps")
    te = [r["te"] for r in noisy.errors if r["matched"]]
    assert te == [r["te"] for r in again.errors if r["matched"]]  # seeded
    assert np.median(te) > 1e-3  # pixels of noise are millimetres in depth
    # its own stream: the other options' draws (here which targets are dropped) do not move
    dropped = {(r["scene_id"], r["im_id"], r["gt_id"]) for r in run(drop_rate=0.5).errors if not r["matched"]}
    both = {(r["scene_id"], r["im_id"], r["gt_id"]) for r in run(drop_rate=0.5, keypoint_noise_px=3.0).errors
            if not r["matched"]}
    assert dropped and dropped == both
    with pytest.raises(Exception, match="keypoint_noise_px must be >= 0"):
        run(keypoint_noise_px=-1.0)
    with pytest.raises(Exception, match="keypoints must be one of bbox, fps"):
        run(keypoint_noise_px=1.0, keypoints="corners")


def test_raising_estimator_is_recorded_and_run_completes(small_dataset, tmp_path):
    rep = evaluate(small_dataset, Raising(), out_dir=tmp_path, progress=False, vsd=False)
    assert rep.num_images == 6
    fails = [f for f in rep.failures if f["kind"] == "exception"]
    assert len(fails) == 2 and all("RuntimeError: boom" in f["message"] for f in fails)
    assert rep.overall["num_matched"] == 0 and rep.overall["auc_adds"] == 0.0 and rep.overall["ar"] == 0.0
    assert "RuntimeError: boom" in (tmp_path / "failures.csv").read_text()


def test_nan_estimates_are_failures(small_dataset):
    rep = evaluate(small_dataset, NaNPose(), progress=False, vsd=False, max_images=2)
    assert rep.overall["num_estimates"] == 0
    assert rep.failures and all(f["kind"] == "invalid-estimate" and "non-finite" in f["message"]
                                for f in rep.failures)


def test_bop_results_round_trip_and_errors(tmp_path):
    rng = np.random.default_rng(0)
    q, _ = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.linalg.det(q))
    rows = [ResultRow(scene_id=1, im_id=2, obj_id=7, score=0.5, R=q, t=np.array([0.01, -0.02, 0.834]), time=0.25),
            ResultRow(scene_id=1, im_id=3, obj_id=22, score=1.0, R=np.eye(3), t=np.array([0.0, 0.0, 1.0]))]
    path = write_bop_results(tmp_path / "r.csv", rows)
    lines = path.read_text().splitlines()
    assert lines[0] == "scene_id,im_id,obj_id,score,R,t,time"
    assert lines[2].split(",")[5] == "0.0 0.0 1000.0"  # t in millimetres
    back = read_bop_results(path)
    for a, b in zip(rows, back):
        assert (a.scene_id, a.im_id, a.obj_id, a.score, a.time) == (b.scene_id, b.im_id, b.obj_id, b.score, b.time)
        np.testing.assert_array_equal(a.R, b.R)
        np.testing.assert_allclose(a.t, b.t, rtol=0, atol=1e-15)
    bad = tmp_path / "bad.csv"
    bad.write_text(lines[0] + "\n" + lines[1] + "\n1,3,22,1.0,1 0 0 0 1 0 0 0,0 0 1000,-1\n")
    with pytest.raises(DatasetError, match=r"bad.csv:3: field 'R' must hold 9"):
        read_bop_results(bad)
    bad.write_text(lines[0] + "\n1,x,22,1.0,1 0 0 0 1 0 0 0 1,0 0 1000,-1\n")
    with pytest.raises(DatasetError, match=r"bad.csv:2: field 'im_id' must be an integer"):
        read_bop_results(bad)
    bad.write_text("scene_id,im_id,obj_id\n")
    with pytest.raises(DatasetError, match="header"):
        read_bop_results(bad)


def test_score_results_reproduces_runner_metrics(small_dataset, tmp_path):
    rep = evaluate(small_dataset, "oracle", estimator_options={"rot_noise_deg": 4.0, "trans_noise_mm": 6.0,
                                                             "drop_rate": 0.2},
                   out_dir=tmp_path / "run", progress=False)
    again = score_results(tmp_path / "run" / "results.csv", small_dataset, out_dir=tmp_path / "score",
                          progress=False)
    skip = {"num_failures", "num_image_exceptions", "mean_time_per_image_s", "median_time_per_image_s"}
    for k, v in rep.overall.items():
        if k in ("ci95", "ci95_scenes"):  # the intervals of the proportions: same counts, same intervals
            assert again.overall[k] == v
        elif k not in skip:
            assert again.overall[k] == pytest.approx(v, rel=1e-9, abs=1e-12, nan_ok=True), k
    assert rep.overall["num_matched"] < rep.overall["num_targets"]  # dropped targets are misses
    for o in rep.per_object:
        assert again.per_object[o]["ar"] == pytest.approx(rep.per_object[o]["ar"], rel=1e-9)
    assert (tmp_path / "score" / "metrics.md").is_file()


def test_cli_eval_runs_and_scores(small_dataset, tmp_path, capsys):
    from simtest.cli import main

    out = tmp_path / "cli"
    assert main(["eval", "--data", str(small_dataset), "--estimator", "oracle", "--opt", "rot_noise_deg=2",
                 "--opt", "seed=1", "--max-images", "2", "--no-vsd", "--no-progress", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    assert "| **All** |" in text and "results.csv" in text and "ADD(-S)-0.1d" in text
    settings = json.loads((out / "metrics.json").read_text())["settings"]
    assert settings["estimator_options"] == {"rot_noise_deg": 2, "seed": 1}
    assert main(["eval", "--results", str(out / "results.csv"), "--data", str(small_dataset), "--max-images", "2",
                 "--no-vsd", "--no-progress", "--out", str(tmp_path / "s")]) == 0
    assert main(["eval", "--data", str(small_dataset), "--estimator", "oracle", "--opt", "bogus",
                 "--out", str(tmp_path / "x")]) == 2
    assert "KEY=VALUE" in capsys.readouterr().err


def test_describe_dataset_counts_images_and_instances(small_dataset):
    from simtest.io import bop
    from simtest.io.dataset import describe_dataset

    text = describe_dataset(small_dataset)
    n_img = sum(len(bop.read_scene(d)) for d in bop.scene_dirs(small_dataset / "train_pbr"))
    assert f"{n_img} RGB-D images" in text and "instances per object" in text


class ScaledOracle:
    """The ground-truth pose with a category-level scale that depends on the image (1 on image 0)."""

    needs_gt = True

    def estimate(self, observation):
        s = 1.0 + 0.25 * observation.im_id
        return [PoseEstimate(o, R, t, scale=s) for o, (R, t) in zip(observation.target_obj_ids,
                                                                      observation.gt_poses)]


def test_estimated_scales_reach_the_error_rows_of_their_own_estimates(small_dataset, tmp_path):
    rep = evaluate(small_dataset, ScaledOracle(), progress=False, vsd=False)
    rows = [r for r in rep.errors if r["matched"]]
    assert rows and {r["im_id"] for r in rows} >= {0, 1}
    for r in rows:
        assert r.get("scale", 1.0) == pytest.approx(1.0 + 0.25 * r["im_id"]), r  # unit scales are left out
