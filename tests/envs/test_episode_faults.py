"""Estimator faults in closed-loop episodes: each ends its episode with a recorded reason and message, the
runner goes on, and the next episode runs normally."""

from __future__ import annotations

import csv
import json
import sys
import time
from types import SimpleNamespace

import numpy as np
import pytest

from simtest.envs.episode import FAILURE_REASONS, run_episode
from simtest.envs.summary import CSV_COLUMNS, summarize
from simtest.estimators.base import PoseEstimate
from simtest.estimators.oracle import OracleEstimator


class Sleeper:
    def estimate(self, observation):
        time.sleep(30)
        return []


class Exits:
    def estimate(self, observation):
        sys.exit(3)


class ReturnsNone:
    def estimate(self, observation):
        return None


class FlatRotation:
    def estimate(self, observation):
        return [SimpleNamespace(obj_id=observation.target_obj_ids[0], R=np.eye(2), t=np.zeros(3))]


class SlowFirst:
    """Hangs on its first call, then returns the ground truth (an oracle)."""

    needs_gt = True

    def __init__(self):
        self.calls = 0

    def estimate(self, observation):
        self.calls += 1
        if self.calls == 1:
            time.sleep(30)
        R, t = observation.gt_poses[0]
        return [PoseEstimate(obj_id=observation.target_obj_ids[0], R=R, t=t)]


def test_timeout_ends_the_episode_and_the_next_runs_normally(env):
    res = run_episode(env, Sleeper(), seed=4, options={"target": "box_1"}, timeout=1)
    assert not res.success and res.reason == "estimator_timeout" and "estimator_timeout" in FAILURE_REASONS
    assert "1 s time limit" in res.error and np.isnan(res.add_s) and res.grasp_index == -1
    after = run_episode(env, OracleEstimator(), seed=3, options={"target": "box_1"}, timeout=1)
    assert after.reason == "none" and after.success and after.add_s < 1e-6


@pytest.mark.parametrize("estimator, words", [
    (Exits(), "sys.exit(3)"),
    (ReturnsNone(), "estimate() returned None; expected a list of PoseEstimate"),
    (FlatRotation(), "R must be 3x3 and t 3 values"),
])
def test_faulty_estimators_are_estimator_errors(env, estimator, words):
    res = run_episode(env, estimator, seed=4, options={"target": "box_1"})
    assert not res.success and res.reason == "estimator_error"
    assert words in res.error and np.isnan(res.add_s)


def test_grasp_cli_records_a_timeout_and_goes_on(tmp_path, capsys):
    from simtest.cli import main

    out = tmp_path / "run"
    assert main(["grasp", "--estimator", f"{__name__}:SlowFirst", "--episodes", "2", "--target", "box_1",
                 "--width", "96", "--timeout", "1", "--out", str(out), "--quiet"]) == 0
    assert "| estimator_timeout | 1 |" in capsys.readouterr().out
    with (out / "episodes.csv").open(newline="") as f:
        first, second = list(csv.DictReader(f))
    assert first["reason"] == "estimator_timeout" and "1 s time limit" in first["error"]
    assert second["reason"] not in ("estimator_timeout", "estimator_error", "no_estimate")
    assert float(second["add_s"]) < 1e-6
    summary = json.loads((out / "summary.json").read_text())
    assert summary["by_reason"]["estimator_timeout"] == 1 and summary["config"]["timeout"] == 1.0
    assert main(["grasp", "--estimator", "oracle", "--timeout", "-2", "--out", str(tmp_path / "x"),
                 "--quiet"]) == 2


class OtherTarget:
    """The ground truth, but answering target 1 (an episode has only target 0)."""

    needs_gt = True

    def estimate(self, observation):
        R, t = observation.gt_poses[0]
        return [PoseEstimate(obj_id=observation.target_obj_ids[0], R=R, t=t, target_index=1)]


class GivesUp:
    def __init__(self):
        self.last_failures = []

    def estimate(self, observation):
        self.last_failures = [{"obj_id": observation.target_obj_ids[0], "reason": "only 3 depth points"}]
        return []


class TurnedCan:
    """The ground truth turned 90 degrees about the can's axis of symmetry (model z): a correct pose."""

    needs_gt = True

    def estimate(self, observation):
        R, t = observation.gt_poses[0]
        Rz = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
        return [PoseEstimate(obj_id=observation.target_obj_ids[0], R=R @ Rz, t=t)]


def test_estimates_for_another_target_index_are_noted_not_dropped_silently(env):
    res = run_episode(env, OtherTarget(), seed=4, options={"target": "box_1"})
    assert res.reason == "no_estimate" and "target_index 1" in res.warnings and "target_index 1" in res.error
    assert "warnings" in res.to_row()


def test_the_estimators_own_failure_reason_explains_a_missing_estimate(env):
    res = run_episode(env, GivesUp(), seed=4, options={"target": "box_1"})
    assert res.reason == "no_estimate" and res.error == "only 3 depth points" and res.warnings == ""


def test_grasp_rotation_error_is_symmetric_as_in_eval(env):
    res = run_episode(env, TurnedCan(), seed=3, options={"target": "can_0"})
    assert res.re_deg == pytest.approx(90.0, abs=1e-6) and res.re_sym_deg < 1.0
    rows = [{**res.to_row(), "episode": 0}]
    assert summarize(rows)["median_re_deg"] == pytest.approx(res.re_sym_deg)


def test_raising_estimator_leaves_its_traceback(env):
    class Raises:
        def estimate(self, observation):
            raise KeyError("weights")

    res = run_episode(env, Raises(), seed=4, options={"target": "box_1"})
    assert res.reason == "estimator_error" and "in estimate: raise KeyError" in res.traceback
    assert "Traceback (most recent call last)" in res.trace and "trace" not in CSV_COLUMNS


def test_gif_frames_play_at_the_given_rate(tmp_path):
    from PIL import Image

    from simtest.io.video import write_video

    frames = [np.full((16, 24, 3), 40 * i, np.uint8) for i in range(4)]
    path = write_video(frames, tmp_path / "clip.gif", fps=10.0)
    if path.suffix == ".gif":
        with Image.open(path) as im:
            assert im.n_frames == 4 and im.info["duration"] == 100  # milliseconds
    else:  # an ffmpeg backend is installed: MP4 at 10 fps
        import imageio.v3 as iio

        assert iio.immeta(path)["fps"] == pytest.approx(10.0)
