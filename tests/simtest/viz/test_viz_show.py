"""``simtest show`` on a generated dataset and on evaluation runs of it: PNGs of the expected size, the right
cards, and one clear error line (rc 2) for bad input."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

from simtest.cli import main
from simtest.evaluation.run import evaluate
from simtest.io.dataset import select_images
from simtest.objects.loaders import load_dataset_objects
from simtest.viz.dataset_page import dataset_card
from simtest.viz.eval_page import load_eval_run, worst_targets


class RaisingOnImage1:
    def estimate(self, observation):
        if observation.im_id == 1:
            raise RuntimeError("no pose for image 1")
        return []


@pytest.fixture(scope="module")
def oracle_run(small_dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("run") / "oracle"
    evaluate(small_dataset, "oracle", estimator_options={"rot_noise_deg": 10.0, "trans_noise_mm": 20.0},
             out_dir=out, progress=False, vsd=False)
    return out


def _png(path):
    img = cv2.imread(str(path), cv2.IMREAD_COLOR)
    assert img is not None, path
    return img


def _one_error_line(capsys, *needles):
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("simtest show: error: "), err
    for n in needles:
        assert n in err[0], (n, err)
    return err[0]


def test_one_image_card_is_written_at_the_expected_size(small_dataset, tmp_path, capsys):
    out = tmp_path / "one.png"
    assert main(["show", str(small_dataset), "--scene", "0", "--image", "1", "--scale", "1", "--out", str(out)]) == 0
    assert "wrote" in capsys.readouterr().out
    img = _png(out)
    # RGB panel | depth panel, 160 px each with a 6 px gap; text strips above and below.
    assert img.shape[1] == 2 * 160 + 6 and img.shape[0] > 120 + 40
    objects = load_dataset_objects(small_dataset)
    ref = [r for r in select_images(small_dataset, "train_pbr", [0], None, objects.ids) if r.im_id == 1][0]
    assert dataset_card(ref, objects, 1).shape == img.shape


def test_contact_sheet_upscales_small_images(small_dataset, tmp_path):
    out = tmp_path / "sheet.png"
    assert main(["show", str(small_dataset), "--images", "4", "--out", str(out)]) == 0
    img = _png(out)
    card_w = 2 * 640 + 6  # 160x120 images enlarged 4x to 640x480 so labels stay legible
    assert img.shape[1] == 2 * card_w + 12 and img.shape[0] > 2 * 480


def test_out_folder_gets_one_png_per_image(small_dataset, tmp_path):
    out = tmp_path / "cards"
    assert main(["show", str(small_dataset), "--scene", "1", "--images", "10", "--out", str(out)]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["card_000.png", "card_001.png", "card_002.png"]


def test_bad_input_is_one_error_line_with_rc_2(small_dataset, tmp_path, capsys):
    empty = tmp_path / "empty"
    empty.mkdir()
    assert main(["show", str(empty), "--out", str(tmp_path / "x.png")]) == 2
    _one_error_line(capsys, str(empty), "is not a BOP dataset")
    assert main(["show", str(tmp_path / "nope"), "--out", str(tmp_path / "x.png")]) == 2
    _one_error_line(capsys, str(tmp_path / "nope"), "does not exist")
    assert main(["show", str(small_dataset), "--scene", "99", "--out", str(tmp_path / "x.png")]) == 2
    _one_error_line(capsys, "scenes [99] not in", "available: [0, 1]")
    assert main(["show", str(small_dataset), "--scene", "0", "--image", "42", "--out", str(tmp_path / "x.png")]) == 2
    _one_error_line(capsys, "image 42 is not in scene 0")
    assert main(["show", str(small_dataset), "--split", "test", "--out", str(tmp_path / "x.png")]) == 2
    _one_error_line(capsys, "no split folder 'test'", "train_pbr")
    assert not (tmp_path / "x.png").exists()


def test_eval_page_draws_every_scored_image(oracle_run, tmp_path, capsys):
    out = tmp_path / "eval.png"
    assert main(["show", str(oracle_run), "--images", "2", "--scale", "1", "--out", str(out)]) == 0
    assert "eval: 2 cards" in capsys.readouterr().out
    img = _png(out)
    assert img.shape[1] == 2 * 160 + 12
    # The estimate colour (magenta) and the ground-truth colour (green) are both on the page.
    rgb = img[..., ::-1].astype(int)
    assert (np.abs(rgb - (255, 40, 220)).sum(axis=-1) < 30).sum() > 50
    assert (np.abs(rgb - (40, 220, 60)).sum(axis=-1) < 30).sum() > 50


def test_a_run_that_scored_a_results_file_draws_that_files_estimates(oracle_run, small_dataset, tmp_path,
                                                                    monkeypatch):
    """``simtest eval --results CSV`` writes no results.csv of its own: the page reads the CSV its settings name
    (here given relative to the folder the run sits in) and labels the run by it; with the CSV gone it draws the
    ground truth alone."""
    import shutil

    (tmp_path / "mine.csv").write_bytes((oracle_run / "results.csv").read_bytes())
    monkeypatch.chdir(tmp_path)
    assert main(["eval", "--data", str(small_dataset), "--results", "mine.csv", "--no-vsd", "--quiet",
                 "--out", "scored"]) == 0
    monkeypatch.chdir(oracle_run.parent)  # the CSV is found beside the run folder, not only from where it was made
    scored = tmp_path / "scored"
    assert not (scored / "results.csv").exists()
    run = load_eval_run(scored)
    assert run.estimator == "results mine.csv" and len(run.estimates) == len(load_eval_run(oracle_run).estimates) > 0
    out = tmp_path / "scored.png"
    assert main(["show", str(scored), "--images", "1", "--scale", "1", "--out", str(out)]) == 0
    rgb = _png(out)[..., ::-1].astype(int)
    assert (np.abs(rgb - (255, 40, 220)).sum(axis=-1) < 30).sum() > 50  # the estimates are drawn
    shutil.move(tmp_path / "mine.csv", tmp_path / "gone.csv")
    assert load_eval_run(scored).estimates == []


def test_worst_targets_rank_by_the_error_column(oracle_run, tmp_path):
    run = load_eval_run(oracle_run)
    worst = worst_targets(run, 3, by="re")
    rest = [e.values["re"] for e in run.errors if e not in worst]
    assert [w.values["re"] for w in worst] == sorted((w.values["re"] for w in worst), reverse=True)
    assert min(w.values["re"] for w in worst) >= max(rest)
    for e in run.errors:  # correct = ADD(-S) below a tenth of the diameter, as the run scored it
        assert e.correct == (e.matched and e.values["add_s_or_add"] < 0.1 * e.diameter_m)
    out = tmp_path / "worst.png"
    assert main(["show", str(oracle_run), "--worst", "3", "--by", "re", "--out", str(out)]) == 0
    img = _png(out)
    assert img.shape[1] == 2 * (640 + 6 + 480) + 12  # image | square zoom, two cards a row


def test_failures_page_and_a_run_without_its_dataset(small_dataset, tmp_path, capsys):
    run_dir = tmp_path / "raising"
    evaluate(small_dataset, RaisingOnImage1(), out_dir=run_dir, progress=False, vsd=False)
    capsys.readouterr()  # the run's own warnings
    out = tmp_path / "fail"
    assert main(["show", str(run_dir), "--failures", "--out", str(out)]) == 0
    assert len(list(out.iterdir())) == 1 + 2  # the summary and the two images with id 1 (one per scene)
    assert main(["show", str(run_dir), "--by", "colour", "--worst", "2", "--out", str(tmp_path / "w.png")]) == 2
    _one_error_line(capsys, "--by must be one of", "'colour'")
    moved = tmp_path / "gone"
    assert main(["show", str(run_dir), "--data", str(moved), "--out", str(tmp_path / "w.png")]) == 2
    _one_error_line(capsys, str(moved), "does not exist")


def test_drawing_takes_well_under_a_second_per_image(small_dataset):
    import time

    objects = load_dataset_objects(small_dataset)
    refs = select_images(small_dataset, "train_pbr", None, None, objects.ids)
    dataset_card(refs[0], objects)  # warm the model caches
    t0 = time.perf_counter()
    for ref in refs:
        dataset_card(ref, objects)
    ms = (time.perf_counter() - t0) * 1000.0 / len(refs)
    assert math.isfinite(ms) and ms < 1000.0, ms


def test_palette_pngs_are_smaller_and_the_same_size(small_dataset, tmp_path):
    from PIL import Image

    full, small = tmp_path / "full.png", tmp_path / "small.png"
    assert main(["show", str(small_dataset), "--image", "0", "--out", str(full)]) == 0
    assert main(["show", str(small_dataset), "--image", "0", "--palette", "--out", str(small)]) == 0
    with Image.open(small) as im:
        assert im.mode == "P" and im.size == _png(full).shape[1::-1]
    assert small.stat().st_size < full.stat().st_size
