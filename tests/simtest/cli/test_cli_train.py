"""``simtest train``: a mixture of datasets with stated weights, the zoom-in keypoint network, resume."""

from __future__ import annotations

import json

import pytest

from simtest.cli import main

torch = pytest.importorskip("torch")


def test_train_keypoints_on_a_mixture_and_resume(small_dataset, tmp_path, capsys):
    out = tmp_path / "run"
    argv = ["train", "keypoints", "--data", str(small_dataset), "--data", str(small_dataset),
            "--data-weights", "0.7,0.3", "--out", str(out), "--epochs", "1", "--batch-size", "2",
            "--crop", "64x64", "--widths", "8,16,16,16", "--decoder", "16,16", "--augment", "none",
            "--workers", "0", "--threads", "1", "--quiet"]
    assert main(argv) == 0
    ck = torch.load(out / "model.pt", weights_only=True)
    assert ck["format"] == "simtest-keypoints/2"
    assert ck["train"]["data_weights"] == [0.7, 0.3] and len(ck["train"]["data"]) == 2
    assert ck["net"]["crop_size"] == 64 and ck["train"]["arch"] == "crop"
    argv[argv.index("--epochs") + 1] = "2"
    assert main(argv + ["--resume"]) == 0
    hist = json.loads((out / "history.json").read_text())
    assert [h["epoch"] for h in hist] == [0, 1]
    capsys.readouterr()
    assert main(argv[:6] + ["--data-weights", "1", "--out", str(tmp_path / "bad")]) == 2
    assert "--data-weights must be 2" in capsys.readouterr().err


def test_train_segmentation_on_a_mixture(small_dataset, tmp_path):
    out = tmp_path / "seg"
    assert main(["train", "segmentation", "--data", str(small_dataset), "--data", str(small_dataset),
                 "--out", str(out), "--epochs", "1", "--batch-size", "2", "--crop", "64x64",
                 "--widths", "8,8,16,16", "--max-images", "2", "--augment", "none", "--threads", "1",
                 "--quiet"]) == 0
    ck = torch.load(out / "model.pt", weights_only=True)
    assert ck["train"]["data_weights"] is None and len(ck["train"]["data"]) == 2
