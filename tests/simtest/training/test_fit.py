"""simtest.training: both networks' trainers run the one loop (:func:`simtest.training.fit.fit`), so a run
stopped after an epoch and resumed ends with exactly the weights, optimiser state and history of an
uninterrupted run, for the keypoint network and the segmentation network alike (real generated data, real
training, no mocks)."""

from __future__ import annotations

import warnings
from pathlib import Path

import pytest

torch = pytest.importorskip("torch")

from simtest.errors import ConfigError  # noqa: E402
from simtest.training.fit import eta_text  # noqa: E402
from simtest.training.keypoints import TrainConfig, train_keypoints  # noqa: E402
from simtest.training.segmentation import SegTrainConfig, train_segmentation  # noqa: E402

#: History entries that are wall times (they differ between any two runs).
TIMES = ("train_seconds", "val_seconds")


class Stop(Exception):
    """Raised from the log after the first epoch: the run stops as a killed one would (last.pt holds epoch 1)."""


def stop_at_second_epoch(line: str) -> None:
    if line.startswith("epoch 2/"):
        raise Stop(line)


@pytest.fixture(scope="module")
def tiny_dataset(tmp_path_factory, small_config):
    """2 scenes x 3 frames of builtin-small objects at 64x48."""
    from simtest.generators.pipeline import generate

    out = tmp_path_factory.mktemp("fitds") / "tiny"
    generate(small_config.replace(**{"camera.width": 64, "camera.height": 48}), out, progress=False)
    return out


def _untimed(history: list[dict]) -> list[dict]:
    return [{k: v for k, v in h.items() if k not in TIMES} for h in history]


def _assert_same_state(a: Path, b: Path) -> None:
    """Two checkpoints hold the same tensors (model and optimiser), epoch and untimed history."""
    ca, cb = torch.load(a, weights_only=True), torch.load(b, weights_only=True)
    assert ca["epoch"] == cb["epoch"] and ca["format"] == cb["format"]
    assert list(ca["model"]) == list(cb["model"])
    for k in ca["model"]:
        assert torch.equal(ca["model"][k], cb["model"][k]), k
    if ca["optimizer"] is not None:
        sa, sb = ca["optimizer"]["state"], cb["optimizer"]["state"]
        assert sorted(sa) == sorted(sb)
        for i in sa:
            for k in sa[i]:
                assert torch.equal(sa[i][k], sb[i][k]), (i, k)
        assert ca["optimizer"]["param_groups"] == cb["optimizer"]["param_groups"]
    assert _untimed(ca["history"]) == _untimed(cb["history"])


def _resume_equals_uninterrupted(train, cfg_type, tmp_path: Path, **settings) -> None:
    whole = train(cfg_type(out=str(tmp_path / "whole"), **settings), progress=False, log=lambda s: None)
    stopped = cfg_type(out=str(tmp_path / "stopped"), **settings)
    with pytest.raises(Stop):
        train(stopped, progress=False, log=stop_at_second_epoch)
    assert torch.load(tmp_path / "stopped" / "last.pt", weights_only=True)["epoch"] == 0
    assert not (tmp_path / "stopped" / "model.pt").exists()
    with pytest.raises(ConfigError, match="already holds a run"):
        train(stopped, progress=False, log=lambda s: None)
    lines: list[str] = []
    resumed = train(stopped, resume=True, progress=False, log=lines.append)
    assert lines[0].startswith("resuming") and "after epoch 1 of 2" in lines[0]
    assert [h["epoch"] for h in resumed.history] == [0, 1]
    _assert_same_state(whole.last_path, resumed.last_path)
    _assert_same_state(whole.model_path, resumed.model_path)
    assert resumed.model_path.with_suffix(".onnx").is_file()


def test_keypoint_run_resumed_after_an_epoch_equals_an_uninterrupted_one(tiny_dataset, tmp_path):
    _resume_equals_uninterrupted(train_keypoints, TrainConfig, tmp_path, data=str(tiny_dataset), arch="crop",
                                 crop=(32, 32), epochs=2, batch_size=2, workers=0, widths=(8, 8, 16, 16),
                                 decoder=(16, 16), hypotheses=2, augment=("weather",), seed=5, threads=1)


def test_segmentation_run_resumed_after_an_epoch_equals_an_uninterrupted_one(tiny_dataset, tmp_path):
    _resume_equals_uninterrupted(train_segmentation, SegTrainConfig, tmp_path, data=str(tiny_dataset), epochs=2,
                                 batch_size=2, widths=(8, 8, 16, 16), augment=("weather",), seed=5, threads=1)


def test_both_trainers_keep_the_best_validated_epoch_and_log_the_time_left(tiny_dataset, tmp_path):
    """The loop's validation, best epoch and progress lines are the same for both networks."""
    runs = {
        "keypoints": (train_keypoints, TrainConfig(data=str(tiny_dataset), out=str(tmp_path / "kp"), arch="full",
                                                   val=str(tiny_dataset), val_images=2, epochs=2, batch_size=3,
                                                   workers=0, widths=(8, 8, 16, 16), decoder=(8, 8), seed=2,
                                                   threads=1), "val_add_s_or_add_01d", "ADD(-S)-0.1d"),
        "segmentation": (train_segmentation, SegTrainConfig(data=str(tiny_dataset), out=str(tmp_path / "seg"),
                                                            val=str(tiny_dataset), val_images=2, epochs=2,
                                                            batch_size=3, widths=(8, 8, 16, 16), seed=2,
                                                            threads=1), "val_miou", "mIoU"),
    }
    for name, (train, cfg, score, label) in runs.items():
        lines: list[str] = []
        res = train(cfg, progress=False, log=lines.append)
        assert [h["epoch"] for h in res.history] == [0, 1], name
        assert all(score in h and h["val_seconds"] >= 0 and h["train_seconds"] >= 0 for h in res.history), name
        best = max(range(2), key=lambda e: (res.history[e][score], -e))
        assert torch.load(res.best_path, weights_only=True)["epoch"] == best, name
        assert lines[0].startswith("epoch 1/2: loss ") and f"; val {label} " in lines[0], (name, lines)
        assert lines[0].endswith(" left)") and not lines[1].endswith(" left)"), (name, lines)


def test_time_left_is_written_in_readable_units():
    assert [eta_text(s) for s in (0.2, 40, 12 * 60, 2.5 * 3600)] == ["0 s", "40 s", "12 min", "2.5 h"]


def test_the_old_trainer_paths_import_the_new_modules_with_a_warning():
    import importlib
    import sys

    for old, new in (("simtest.estimators.keypoints.train", "simtest.training.keypoints"),
                     ("simtest.estimators.segicp.train", "simtest.training.segmentation"),
                     ("simtest.estimators.training", "simtest.training")):
        sys.modules.pop(old, None)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            module = importlib.import_module(old)
        assert module is importlib.import_module(new)
        assert any(issubclass(w.category, DeprecationWarning) and new in str(w.message) for w in caught), old
    from simtest.estimators.blocks import init_conv_weights
    from simtest.estimators.onnx_net import check_device
    from simtest.training import init_conv_weights as old_init
    from simtest.training import check_device as old_check

    assert old_init is init_conv_weights and old_check is check_device
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        from simtest.estimators.keypoints.checkpoint import object_record
    from simtest.estimators.checkpoint import object_record as shared

    assert object_record is shared
    assert any("simtest.estimators.checkpoint" in str(w.message) for w in caught)
