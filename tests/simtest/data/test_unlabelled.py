"""Unlabelled target splits (``--unlabelled``): labels withheld but kept, scored by eval, mixed in training."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from simtest.cli import main
from simtest.errors import DatasetError
from simtest.evaluation.run import evaluate
from simtest.generators.pipeline import generate
from simtest.io.scene_folder import UNLABELLED_KEEP


def _files(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def pair(tmp_path_factory, small_config):
    """The same config and seed generated labelled and unlabelled (2 scenes x 2 frames, 96x72)."""
    root = tmp_path_factory.mktemp("unlabelled")
    cfg = small_config.replace(**{"frames_per_scene": 2, "camera.width": 96, "camera.height": 72,
                                  "captions": True})
    generate(cfg, root / "labelled", progress=False)
    generate(cfg.replace(unlabelled=True), root / "target", progress=False)
    return root / "labelled", root / "target"


def test_split_has_no_labels_and_withheld_labels_equal_a_labelled_run(pair):
    labelled, target = pair
    manifest = json.loads((target / "manifest.json").read_text())
    assert manifest["unlabelled"] is True and manifest["config"]["unlabelled"] is True
    assert json.loads((labelled / "manifest.json").read_text())["unlabelled"] is False
    scenes = sorted(p.name for p in (target / "train_pbr").iterdir())
    assert scenes == ["000000", "000001"]
    for scene in scenes:
        split_scene = target / "train_pbr" / scene
        assert sorted(p.name for p in split_scene.iterdir()) == sorted(UNLABELLED_KEEP)
        assert not list(split_scene.rglob("scene_gt*")) and not list(split_scene.rglob("*mask*"))
        lab = _files(labelled / "train_pbr" / scene)
        # the images, depth and cameras in the split, everything else withheld: byte for byte the labelled run
        assert _files(split_scene) == {k: v for k, v in lab.items() if k.split("/")[0] in UNLABELLED_KEEP}
        withheld = _files(target / "withheld" / "train_pbr" / scene)
        assert withheld == {k: v for k, v in lab.items() if k.split("/")[0] not in ("rgb", "depth")}
        assert "scene_gt.json" in withheld and "scene_captions.json" in withheld
        assert any(k.startswith("mask_visib/") for k in withheld)


def test_eval_scores_with_withheld_labels_and_refuses_without(pair, tmp_path, capsys):
    labelled, target = pair
    a = evaluate(target, "oracle", vsd=False, progress=False)
    b = evaluate(labelled, "oracle", vsd=False, progress=False)
    assert a.num_images == b.num_images == 4
    assert a.overall["num_targets"] == b.overall["num_targets"] > 0
    assert a.overall["add_s_or_add_01d"] == pytest.approx(1.0)
    assert [r["obj_id"] for r in a.errors] == [r["obj_id"] for r in b.errors]
    # a copy of the split without its withheld folder: refused, then scored with --labels
    copy = tmp_path / "copy"
    copy.mkdir()
    for name in ("camera.json", "manifest.json", "models", "train_pbr"):
        (copy / name).symlink_to(target / name)
    with pytest.raises(DatasetError, match=r"unlabelled.*withheld labels folder .* is missing.*--labels"):
        evaluate(copy, "oracle", vsd=False, progress=False)
    assert main(["eval", "--estimator", "oracle", "--data", str(copy), "--out", str(tmp_path / "e1"),
                 "--no-vsd", "--quiet"]) == 2
    assert "--labels" in capsys.readouterr().err
    assert main(["eval", "--estimator", "oracle", "--data", str(copy), "--out", str(tmp_path / "e2"), "--no-vsd",
                 "--quiet", "--labels", str(target / "withheld")]) == 0
    metrics = json.loads((tmp_path / "e2" / "metrics.json").read_text())
    assert metrics["overall"]["num_targets"] == a.overall["num_targets"]
    assert metrics["settings"]["labels"] == str(target / "withheld")
    # a split without labels in a dataset whose manifest does not say so: refused, naming the file
    with pytest.raises(DatasetError, match=r"scene_gt.json: file is missing; no ground truth to score.*--labels"):
        evaluate(copy, "oracle", vsd=False, progress=False, split="train_pbr",
                 labels=tmp_path)  # a labels folder without this split


def test_pose_dataset_points_to_the_unlabelled_reader(pair):
    from simtest.data import PoseDataset

    with pytest.raises(DatasetError, match="unlabelled.*UnlabelledDataset"):
        PoseDataset(pair[1])


def test_mixed_loader_yields_both_kinds_deterministically(pair):
    import torch

    from simtest.data import PoseDataset
    from simtest.data.mixing import MixedDataset, UnlabelledDataset, collate_mixed

    labelled, target = pair
    lab = PoseDataset(labelled)
    unl = UnlabelledDataset(target, seed=1)
    assert len(unl) == 4
    s = unl[0]
    assert s["labelled"] is False and tuple(s["rgb"].shape) == (3, 72, 96) and "obj_ids" not in s
    np.testing.assert_array_equal(s["rgb"].numpy(), lab[0]["rgb"].numpy())  # same seed, same image
    mix = MixedDataset([lab, unl], ratio=[1, 3], length=8, seed=5)
    assert mix.counts() == [2, 6]
    mix.set_epoch(0)
    loader = torch.utils.data.DataLoader(mix, batch_size=4, shuffle=False, collate_fn=collate_mixed)
    batches = list(loader)
    flags = torch.cat([b["labelled"] for b in batches])
    assert int(flags.sum()) == 2 and len(flags) == 8
    assert torch.equal(torch.cat([b["source"] for b in batches]), (~flags).long())
    for b in batches:
        assert b["rgb"].shape[0] == 4
        if b["labelled"].any():
            rows = set(b["batch_index"].tolist())
            assert rows == set(torch.nonzero(b["labelled"]).flatten().tolist())
            assert len(b["obj_ids"]) == len(b["batch_index"]) == len(b["R"]) > 0
        else:
            assert "obj_ids" not in b and len(b["batch_index"]) == 0
    order0 = [a.tolist() for a in mix.order()]
    again = MixedDataset([lab, unl], ratio=[1, 3], length=8, seed=5)
    assert [a.tolist() for a in again.order()] == order0
    mix.set_epoch(1)
    assert [a.tolist() for a in mix.order()] != order0 and unl.epoch == 1 and lab.epoch == 1
    # each image of a source at most once per pass through it
    src, idx = mix.order()
    assert sorted(idx[src == 0].tolist()) == sorted(set(idx[src == 0].tolist()))


def test_unlabelled_reader_never_reads_label_files(pair, tmp_path):
    """Any split can be read without its labels: a labelled copy whose scene_gt.json is broken still reads
    (only scene_camera.json, images and depth are opened)."""
    import shutil

    from simtest.data.mixing import UnlabelledDataset

    copy = tmp_path / "copy"
    shutil.copytree(pair[0], copy)
    for gt in (copy / "train_pbr").glob("*/scene_gt.json"):
        gt.write_text("{ not json")
    ds = UnlabelledDataset(copy, seed=0)
    assert len(ds) == 4 and ds.load_numpy(0)["rgb"].shape == (72, 96, 3)
