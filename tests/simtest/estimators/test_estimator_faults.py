"""Estimator faults of any kind (exit, invalid returns, hangs, exceptions) are recorded failures in eval and
sweeps; the run goes on. Ctrl-C still stops it."""

from __future__ import annotations

import csv
import logging
import signal
import sys
import threading
import time
from types import SimpleNamespace as Pose  # pose-like objects a PoseEstimate would refuse at construction

import numpy as np
import pytest

from simtest.errors import ConfigError
from simtest.estimators import PoseEstimate
from simtest.estimators.guard import call_estimator, check_estimate, check_timeout
from simtest.evaluation.run import evaluate
from simtest.sweeps.grid import SweepConfig, run_sweep


class Exits:
    """Calls sys.exit(3) on the second image of each scene; no estimates otherwise."""

    def estimate(self, observation):
        if observation.im_id == 1:
            sys.exit(3)
        return []


class ReturnsNone:
    def estimate(self, observation):
        return None


class ReturnsEmpty:
    def estimate(self, observation):
        return []


class Interrupted:
    def estimate(self, observation):
        raise KeyboardInterrupt


class Sleeper:
    """Hangs in a sleep."""

    def estimate(self, observation):
        time.sleep(30)
        return []


class BusyLoop:
    """Hangs in pure Python, swallowing every Exception it sees."""

    def estimate(self, observation):
        while True:
            try:
                sum(range(1000))
            except Exception:  # noqa: BLE001 - a careless estimator must still be stopped
                pass


class Mixed:
    """One good estimate per target plus a list of bad elements (each case of a malformed estimate)."""

    needs_gt = True

    def estimate(self, observation):
        good = [PoseEstimate(obj_id=o, R=R, t=t) for o, (R, t) in zip(observation.target_obj_ids,
                                                                      observation.gt_poses)]
        o = observation.target_obj_ids[0]
        bad = [{"obj_id": o, "R": np.eye(3), "t": np.zeros(3)},
               Pose(obj_id=o, R=np.eye(2), t=np.zeros(3)),
               Pose(obj_id=o, R=np.eye(3), t=np.zeros(4)),
               Pose(obj_id=o, R=np.eye(3), t=np.array([0.0, np.inf, 1.0])),
               PoseEstimate(obj_id=o, R=2 * np.eye(3), t=np.zeros(3)),
               Pose(obj_id=1.5, R=np.eye(3), t=np.zeros(3)),
               PoseEstimate(obj_id=999, R=np.eye(3), t=np.zeros(3))]
        return good + bad


def _failures_csv(path):
    with (path / "failures.csv").open(newline="") as f:
        return list(csv.DictReader(f))


def test_sys_exit_is_recorded_and_the_run_goes_on(small_dataset, tmp_path):
    rep = evaluate(small_dataset, Exits(), out_dir=tmp_path, progress=False, vsd=False)
    assert rep.num_images == 6
    assert [f["kind"] for f in rep.failures] == ["exit", "exit"]
    rows = _failures_csv(tmp_path)
    assert [(r["im_id"], r["kind"], r["exception_type"], r["obj_id"]) for r in rows] == [
        ("1", "exit", "SystemExit", "")] * 2
    assert len({r["scene_id"] for r in rows}) == 2
    assert all("sys.exit(3)" in r["message"] for r in rows)
    assert (tmp_path / "metrics.json").is_file() and "exit 2" in (tmp_path / "metrics.md").read_text()


def test_keyboard_interrupt_stops_the_run(small_dataset):
    with pytest.raises(KeyboardInterrupt):
        evaluate(small_dataset, Interrupted(), progress=False, vsd=False, max_images=1)


def test_none_return_is_an_invalid_return(small_dataset, tmp_path):
    rep = evaluate(small_dataset, ReturnsNone(), out_dir=tmp_path, progress=False, vsd=False, max_images=2)
    assert len(rep.failures) == 2 and rep.overall["num_estimates"] == 0
    for f in _failures_csv(tmp_path):
        assert f["kind"] == "invalid-return"
        assert f["message"].startswith("estimate() returned None; expected a list of PoseEstimate")


@pytest.mark.parametrize("value, shown", [({"obj_id": 1}, "a dict ({'obj_id': 1})"), ("pose", "a str ('pose')"),
                                          (7, "an int (7)"), ((e for e in []), "a generator")])
def test_non_list_returns_name_what_came_back(value, shown):
    class Returns:
        def estimate(self, observation):
            return value

    out, fault = call_estimator(Returns(), None, timeout=None)
    assert out == [] and fault.kind == "invalid-return"
    assert shown in fault.message and "expected a list of PoseEstimate" in fault.message


def test_malformed_elements_are_named_and_dropped(small_dataset, tmp_path):
    rep = evaluate(small_dataset, Mixed(), out_dir=tmp_path, progress=False, vsd=False, max_images=1)
    n_targets = rep.overall["num_targets"]
    assert rep.overall["num_estimates"] == n_targets and rep.overall["num_matched"] == n_targets
    msgs = [f["message"] for f in rep.failures]
    assert all(f["kind"] == "invalid-estimate" for f in rep.failures) and len(msgs) == 7
    expected = ["is a dict", "R must be 3x3 and t 3 values", "got shapes (3, 3) and (4,)", "non-finite",
                "not a rotation matrix", "obj_id must be an integer, got a float", "unknown obj_id 999"]
    for msg, want in zip(msgs, expected):
        assert want in msg, (msg, want)
    assert all(m.startswith(f"estimate [{n_targets + i}]") for i, m in enumerate(msgs))
    assert rep.failures[-1]["obj_id"] == 999


def test_check_estimate_accepts_pose_like_objects_and_cleans_them():
    class Like:
        obj_id = np.int64(3)
        R = np.eye(3).tolist()
        t = [[0.0], [0.0], [0.5]]

    e, why = check_estimate(Like(), {3})
    assert why is None and e.obj_id == 3 and e.t.shape == (3,) and e.R.dtype == np.float64 and e.score == 1.0


def test_sleeping_estimator_times_out_and_the_run_goes_on(small_dataset, tmp_path):
    rep = evaluate(small_dataset, Sleeper(), out_dir=tmp_path, progress=False, vsd=False, max_images=2, timeout=1)
    assert rep.num_images == 2
    rows = _failures_csv(tmp_path)
    assert [r["kind"] for r in rows] == ["timeout", "timeout"] and rows[0]["im_id"] != rows[1]["im_id"]
    assert "1 s time limit" in rows[0]["message"] and rows[0]["exception_type"] == "TimeoutError"


class Swallows:
    """Turns whatever interrupts its sleep into an error of its own, or returns as if nothing happened."""

    def __init__(self, reraise: bool) -> None:
        self.reraise = reraise

    def estimate(self, observation):
        try:
            time.sleep(30)
        except BaseException as exc:  # noqa: BLE001 - a careless estimator
            if self.reraise:
                raise RuntimeError("interrupted") from exc
        return []


@pytest.mark.parametrize("estimator", [BusyLoop(), Swallows(reraise=True), Swallows(reraise=False)],
                         ids=["busy-loop", "reraises", "swallows"])
def test_careless_estimators_still_time_out(estimator):
    out, fault = call_estimator(estimator, None, timeout=0.5)
    assert out == [] and fault.kind == "timeout" and "0.5 s" in fault.message


def test_timer_and_handler_are_restored():
    def outer(signum, frame):  # pragma: no cover - never fires within the test
        raise AssertionError("outer alarm")

    previous = signal.signal(signal.SIGALRM, outer)
    try:
        signal.setitimer(signal.ITIMER_REAL, 1000.0)
        out, fault = call_estimator(ReturnsEmpty(), None, timeout=5)
        assert fault is None and out == []
        assert signal.getsignal(signal.SIGALRM) is outer
        assert signal.getitimer(signal.ITIMER_REAL)[0] > 0
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, previous)


def test_outside_the_main_thread_runs_without_timeout_and_warns(caplog):
    import simtest.estimators.guard as guard

    guard._warned_no_timeout = False
    got = []
    with caplog.at_level(logging.WARNING, logger="simtest.estimators.guard"):
        for _ in range(2):
            th = threading.Thread(target=lambda: got.append(call_estimator(ReturnsEmpty(), None, timeout=1)))
            th.start()
            th.join()
    assert got == [([], None), ([], None)]
    assert sum("without a timeout" in r.message for r in caplog.records) == 1


@pytest.mark.parametrize("value", [-1, float("nan"), "10", True])
def test_bad_timeouts_are_config_errors(value):
    with pytest.raises(ConfigError, match="timeout must be a number of seconds >= 0"):
        check_timeout(value)
    assert check_timeout(0) is None and check_timeout(None) is None and check_timeout(2) == 2.0


def test_cli_eval_timeout(small_dataset, tmp_path, capsys):
    from simtest.cli import main

    out = tmp_path / "cli"
    assert main(["eval", "--data", str(small_dataset), "--estimator", f"{__name__}:Sleeper", "--timeout", "1",
                 "--max-images", "1", "--no-vsd", "--no-progress", "--out", str(out)]) == 1  # every image failed
    captured = capsys.readouterr()
    assert "failures" in captured.out and "(timeout 1)" in captured.out
    assert "the estimator failed on 1 of 1 images (timeout 1)" in captured.err
    assert [r["kind"] for r in _failures_csv(out)] == ["timeout"]
    assert main(["eval", "--data", str(small_dataset), "--estimator", "oracle", "--timeout", "-1",
                 "--no-progress", "--out", str(tmp_path / "x")]) == 2
    assert "timeout must be" in capsys.readouterr().err


def test_sweep_records_timeouts_in_pose_and_grasp_cells(tmp_path):
    cfg = SweepConfig.from_dict({
        "seed": 0, "timeout": 1,
        "estimators": [{"name": "slow", "estimator": f"{__name__}:Sleeper"}],
        "dataset": {"generate": {"objects": "builtin-small", "scenes": 1, "frames_per_scene": 2,
                                 "camera": {"width": 96, "height": 72}}},
        "factors": {"occlusion": [], "corruptions": [], "depth_noise": []},
        "grasp": {"episodes": 1, "width": 96, "height": 72},
    })
    out = tmp_path / "s"
    rep = run_sweep(cfg, out, progress=False)
    assert sorted(rep.cells_run) == ["slow/clean/grasp", "slow/clean/pose"]
    pose = out / "cells" / "slow" / "clean" / "pose"
    assert [r["kind"] for r in _failures_csv(pose)] == ["timeout", "timeout"]
    with (out / "cells" / "slow" / "clean" / "grasp" / "episodes.csv").open(newline="") as f:
        (row,) = list(csv.DictReader(f))
    assert row["reason"] == "estimator_timeout" and "1 s time limit" in row["error"]
    with pytest.raises(ConfigError, match=r"timeout = -1 is invalid"):
        SweepConfig.from_dict({**cfg.to_dict(), "timeout": -1})


class SlowToPrepare:
    """Takes 1.5 s to prepare (a cache being built), then answers at once; counts its calls."""

    calls: list[str] = []

    def prepare(self, objects):
        SlowToPrepare.calls.append(f"prepare {len(objects.ids)}")
        time.sleep(1.5)

    def estimate(self, observation):
        SlowToPrepare.calls.append("estimate")
        return []


class DeclaresTime(ReturnsEmpty):
    time_limit_s = 600.0


class DeclaresNonsense(ReturnsEmpty):
    time_limit_s = -5


def test_prepare_runs_once_before_the_images_outside_their_time_limit(small_dataset, tmp_path):
    SlowToPrepare.calls.clear()
    rep = evaluate(small_dataset, SlowToPrepare(), out_dir=tmp_path, progress=False, vsd=False, max_images=2,
                   timeout=1)
    assert [c.split()[0] for c in SlowToPrepare.calls] == ["prepare", "estimate", "estimate"]
    assert not [r for r in _failures_csv(tmp_path) if r["kind"] == "timeout"]  # the 1.5 s were not an image's
    assert rep.settings["timeout_s"] == 1.0


def test_the_default_time_limit_follows_what_the_estimator_declares(small_dataset, tmp_path):
    from simtest.estimators.guard import AUTO_TIMEOUT, DEFAULT_TIMEOUT_S, resolve_timeout

    assert resolve_timeout(AUTO_TIMEOUT, ReturnsEmpty()) == DEFAULT_TIMEOUT_S == 120.0
    assert resolve_timeout(AUTO_TIMEOUT, DeclaresTime()) == 600.0
    short = DeclaresTime()
    short.time_limit_s = 30.0  # shorter than the default: the default holds
    assert resolve_timeout(AUTO_TIMEOUT, short) == 120.0
    assert resolve_timeout(5, DeclaresTime()) == 5.0 and resolve_timeout(0, DeclaresTime()) is None
    with pytest.raises(ConfigError, match="DeclaresNonsense.time_limit_s must be a positive number of seconds, got -5"):
        resolve_timeout(AUTO_TIMEOUT, DeclaresNonsense())
    rep = evaluate(small_dataset, DeclaresTime(), out_dir=tmp_path / "auto", progress=False, vsd=False, max_images=1)
    assert rep.settings["timeout_s"] == 600.0  # no timeout given: the declared one
    rep = evaluate(small_dataset, DeclaresTime(), out_dir=tmp_path / "given", progress=False, vsd=False,
                   max_images=1, timeout=7)
    assert rep.settings["timeout_s"] == 7.0  # the user's choice wins
