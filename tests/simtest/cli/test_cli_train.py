"""``simtest train``: a mixture of datasets with stated weights, the zoom-in keypoint network, resume, warm start."""

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
    # warm start from that run: same network, recorded; another network is refused with the differing field
    warm = [a if a != str(out) else str(tmp_path / "warm") for a in argv]
    warm[warm.index("--epochs") + 1] = "1"
    assert main(warm + ["--init", str(out / "model.pt")]) == 0
    assert torch.load(tmp_path / "warm" / "model.pt", weights_only=True)["train"]["init"] == str(out / "model.pt")
    capsys.readouterr()
    assert main(warm + ["--init", str(out / "model.pt"), "--hypotheses", "2", "--out", str(tmp_path / "w2")]) == 2
    assert "hypotheses 4 there, 2 here" in capsys.readouterr().err
    assert main(["train", "segmentation", "--data", str(small_dataset), "--out", str(tmp_path / "seg"),
                 "--init", str(out / "model.pt"), "--quiet"]) == 2
    assert "not a segmentation checkpoint" in capsys.readouterr().err


def test_train_segmentation_on_a_mixture(small_dataset, tmp_path):
    out = tmp_path / "seg"
    assert main(["train", "segmentation", "--data", str(small_dataset), "--data", str(small_dataset),
                 "--out", str(out), "--epochs", "1", "--batch-size", "2", "--crop", "64x64",
                 "--widths", "8,8,16,16", "--max-images", "2", "--augment", "none", "--threads", "1",
                 "--quiet"]) == 0
    ck = torch.load(out / "model.pt", weights_only=True)
    assert ck["train"]["data_weights"] is None and len(ck["train"]["data"]) == 2


def test_train_outlines_from_the_command_line(small_dataset, tmp_path, capsys):
    """``simtest train outlines``: its own defaults (3 epochs, 32 crops a step) unless given, an ONNX file the
    template estimator takes (``--opt outline=FILE``)."""
    out = tmp_path / "outlines"
    assert main(["train", "outlines", "--data", str(small_dataset), "--val", str(small_dataset), "--val-images", "1",
                 "--out", str(out), "--epochs", "1", "--max-images", "2", "--threads", "1", "--quiet"]) == 0
    ck = torch.load(out / "model.pt", weights_only=True)
    assert ck["format"] == "simtest-outline/1" and ck["train"]["batch_size"] == 32 and ck["net"]["crop_size"] == 128
    assert ck["train"]["target"] == "visible"
    assert (out / "model.onnx").is_file() and "val mask IoU" in capsys.readouterr().out
    from simtest.estimators import load_estimator

    est = load_estimator("templates", outline=str(out / "model.onnx"))
    assert est.outline is not None and est.outline.runtime == "onnx"
    amodal = tmp_path / "amodal"
    assert main(["train", "outlines", "--data", str(small_dataset), "--out", str(amodal), "--epochs", "1",
                 "--max-images", "1", "--threads", "1", "--target", "amodal", "--quiet"]) == 0
    assert torch.load(amodal / "model.pt", weights_only=True)["train"]["target"] == "amodal"
