"""The learned estimators without torch: ONNX files written by training and by `simtest export`, run by ONNX
Runtime with the torch path's outputs, and the commands that use them working with torch made unimportable."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from simtest.errors import ConfigError  # noqa: E402
from simtest.estimators.keypoints.infer import KeypointEstimator, predict_maps, predict_maps_onnx  # noqa: E402
from simtest.training.keypoints import TrainConfig, train_keypoints  # noqa: E402
from simtest.estimators.onnx_export import export_checkpoint  # noqa: E402
from simtest.estimators.onnx_net import OnnxNet, file_sha256, onnx_path_for  # noqa: E402
from simtest.estimators.segicp import SegICPEstimator, Segmenter, default_checkpoint  # noqa: E402
from simtest.evaluation.run import evaluate  # noqa: E402
from simtest.io import bop  # noqa: E402

#: Run a simtest command with torch unimportable (any import of torch or torch.* raises ImportError).
NO_TORCH = """
import sys, importlib.abc
class _NoTorch(importlib.abc.MetaPathFinder):
    def find_spec(self, name, path=None, target=None):
        if name == "torch" or name.startswith("torch."):
            raise ImportError("torch is blocked in this test")
sys.meta_path.insert(0, _NoTorch())
from simtest.cli import main
code = main(sys.argv[1:])
assert "torch" not in sys.modules, "torch was imported"
sys.exit(code)
"""


def test_the_shipped_onnx_file_is_the_export_of_the_shipped_checkpoint(tmp_path):
    """The shipped ONNX file belongs to the shipped checkpoint (its SHA-256 in the metadata) and computes what a
    fresh export of it computes; an export repeated in one environment gives the same bytes (other exporter
    versions may lay the graph out differently, so the shipped file is compared by its outputs)."""
    import hashlib

    ckpt = default_checkpoint()
    shipped = onnx_path_for(ckpt)
    assert shipped.is_file() and shipped.stat().st_size < 5_000_000
    fresh = export_checkpoint(ckpt, tmp_path / "seg.onnx")
    again = export_checkpoint(ckpt, tmp_path / "again.onnx")
    assert hashlib.sha256(fresh.read_bytes()).hexdigest() == hashlib.sha256(again.read_bytes()).hexdigest()
    net, ref = OnnxNet(shipped, "simtest-segmentation/1"), OnnxNet(fresh, "simtest-segmentation/1")
    assert net.meta == ref.meta and net.meta["source_sha256"] == file_sha256(ckpt)
    assert net.meta["objects"]["obj_ids"] == [1, 7, 13, 22] and net.meta["focal_px"] > 0
    x = np.random.default_rng(0).random((2, 4, 240, 320), dtype=np.float32)
    assert np.abs(net.run(x)[0] - ref.run(x)[0]).max() < 1e-4


def test_segicp_onnx_equals_torch_on_real_images(small_dataset, tmp_path):
    """Class probabilities within 1e-4, identical labels, and identical poses through the whole estimator."""
    onnx_seg, torch_seg = Segmenter(runtime="onnx"), Segmenter(runtime="torch")
    assert onnx_seg.runtime == "onnx" and torch_seg.runtime == "torch" and Segmenter().runtime == "onnx"
    from simtest.io.dataset import select_images

    for ref in select_images(small_dataset, "train_pbr", None, 4, [1, 7, 13, 22]):
        rgb = bop.read_image(ref.scene_dir, ref.im_id)
        depth = bop.read_depth(ref.scene_dir, ref.im_id, ref.info["depth_scale"])
        a = onnx_seg.probabilities(rgb, depth, ref.info["K"])
        b = torch_seg.probabilities(rgb, depth, ref.info["K"])
        assert np.abs(a - b).max() < 1e-4
        np.testing.assert_array_equal(a.argmax(0), b.argmax(0))
    reps = [evaluate(small_dataset, SegICPEstimator(runtime=r, coarse_rotations=60, refine_top=1, max_iterations=5),
                     vsd=False, progress=False, max_images=3) for r in ("onnx", "torch")]
    ra, rb = ([(e.scene_id, e.im_id, e.obj_id, e.R.round(9).tolist(), e.t.round(9).tolist()) for e in r.estimates]
              for r in reps)
    assert ra == rb and len(ra) > 0


@pytest.fixture(scope="module")
def kp_run(small_dataset, tmp_path_factory):
    out = tmp_path_factory.mktemp("kpo") / "run"
    cfg = TrainConfig(data=str(small_dataset), out=str(out), epochs=1, batch_size=3, crop=(64, 64), workers=0,
                      widths=(8, 16, 16, 16), decoder=(16, 16), seed=2)
    return train_keypoints(cfg, progress=False, log=lambda s: None)


def test_training_writes_the_onnx_file_and_keypoints_run_it_with_the_torch_maps(kp_run, small_dataset):
    onnx = onnx_path_for(kp_run.model_path)
    assert onnx.is_file() and OnnxNet.source_of(onnx) == file_sha256(kp_run.model_path)
    a, b = KeypointEstimator(kp_run.model_path), KeypointEstimator(kp_run.model_path, runtime="torch")
    assert a.runtime == "onnx" and b.runtime == "torch" and a.checkpoint == str(onnx)
    rgb = np.random.default_rng(0).integers(0, 255, (120, 160, 3), dtype=np.uint8)
    ma, mb = predict_maps_onnx(a.net, rgb), predict_maps(b.model, rgb)
    for k in ("seg", "points", "conf"):
        assert ma[k].shape == mb[k].shape and np.abs(ma[k] - mb[k]).max() < 1e-3, k
    ra = evaluate(small_dataset, a, vsd=False, progress=False, max_images=2)
    rb = evaluate(small_dataset, b, vsd=False, progress=False, max_images=2)
    assert [e.obj_id for e in ra.estimates] == [e.obj_id for e in rb.estimates]
    for ea, eb in zip(ra.estimates, rb.estimates):
        # metres: the same PnP solution up to the runtimes' float32 noise (relative: a one-epoch network may put
        # an object hundreds of metres away)
        np.testing.assert_allclose(ea.t, eb.t, rtol=1e-4, atol=1e-3)


def test_a_stale_onnx_file_is_not_used_and_the_errors_name_the_fix(kp_run, tmp_path):
    run = tmp_path / "run"
    shutil.copytree(Path(kp_run.model_path).parent, run)
    other = run / "last.pt"
    shutil.copy(run / "model.onnx", run / "last.onnx")  # an ONNX file of another checkpoint beside last.pt
    assert KeypointEstimator(other).runtime == "torch"
    with pytest.raises(ConfigError, match=r"runtime=onnx but last.onnx beside it was exported from another "
                                          r"checkpoint; convert it with: simtest export"):
        KeypointEstimator(other, runtime="onnx")
    with pytest.raises(ConfigError, match="runtime=torch needs a .pt checkpoint"):
        KeypointEstimator(run / "model.onnx", runtime="torch")
    with pytest.raises(ConfigError, match="runtime must be one of auto, onnx, torch"):
        KeypointEstimator(run / "model.pt", runtime="tf")
    proc = subprocess.run([sys.executable, "-m", "simtest", "export", str(other)], capture_output=True, text=True)
    assert proc.returncode == 2 and "exists; pass --overwrite" in proc.stderr
    proc = subprocess.run([sys.executable, "-m", "simtest", "export", str(other), "--overwrite"], capture_output=True,
                          text=True)
    assert proc.returncode == 0 and KeypointEstimator(other).runtime == "onnx"
    with pytest.raises(ConfigError, match="not a segmentation, keypoint or outline checkpoint"):
        torch.save({"hello": 1}, tmp_path / "x.pt")
        export_checkpoint(tmp_path / "x.pt")


def _no_torch(*argv: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-c", NO_TORCH, *argv], capture_output=True, text=True, timeout=900)


def test_eval_grasp_and_sweep_with_segicp_run_without_torch(small_dataset, tmp_path):
    proc = _no_torch("eval", "--quiet", "--data", str(small_dataset), "--estimator", "segicp", "--max-images", "2",
                     "--no-vsd", "--out", str(tmp_path / "eval"))
    assert proc.returncode == 0, proc.stderr
    assert "segicp" in proc.stdout and (tmp_path / "eval" / "results.csv").is_file()
    proc = _no_torch("grasp", "--quiet", "--estimator", "segicp", "--episodes", "1", "--width", "160", "--height",
                     "120", "--out", str(tmp_path / "grasp"))
    assert proc.returncode == 0, proc.stderr
    config = tmp_path / "sweep.toml"
    config.write_text(f'seed = 0\nmetrics = ["add_s_or_add_01d"]\n[[estimators]]\nname = "segicp"\n'
                      f'estimator = "segicp"\n[dataset]\npath = "{small_dataset}"\n[factors]\nocclusion = ["L2"]\n'
                      f'corruptions = []\ndepth_noise = []\n[grasp]\nepisodes = 0\n')
    proc = _no_torch("sweep", "--quiet", str(config), "--out", str(tmp_path / "sweep"))
    assert proc.returncode == 0, proc.stderr
    rows = (tmp_path / "sweep" / "summary.csv").read_text()
    assert "segicp" in rows and "L2" in rows
    proc = _no_torch("train", "segmentation", "--data", str(small_dataset), "--out", str(tmp_path / "t"))
    assert proc.returncode == 2 and "simtest train needs PyTorch" in proc.stderr
