"""One writer per output folder (real processes), failure output that scales, and a real full disk."""

from __future__ import annotations

import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from simtest.io.lock import OutputBusyError, lock_path, output_lock

SIMTEST = [sys.executable, "-m", "simtest"]
GEN = ["generate", "--quiet", "--objects", "builtin-small", "--frames-per-scene", "2", "--width", "80",
       "--height", "60", "--objects-per-scene", "2", "3", "--seed", "5"]
#: A child that holds the lock of argv[1] and waits to be killed.
HOLDER = ("import sys, time\nfrom simtest.io.lock import output_lock\n"
          "with output_lock(sys.argv[1], 'simtest generate'):\n    print('held', flush=True)\n    time.sleep(60)\n")


def _hold(folder: Path) -> subprocess.Popen:
    proc = subprocess.Popen([sys.executable, "-c", HOLDER, str(folder)], stdout=subprocess.PIPE, text=True)
    assert proc.stdout.readline().strip() == "held"
    return proc


def test_a_second_run_on_a_held_folder_is_refused_at_once_and_kill_9_leaves_no_stale_lock(tmp_path):
    out = tmp_path / "ds"
    holder = _hold(out)
    try:
        t0 = time.monotonic()
        proc = subprocess.run([*SIMTEST, *GEN, "--scenes", "1", "--out", str(out)], capture_output=True, text=True)
        took = time.monotonic() - t0
        assert proc.returncode == 2, proc.stderr
        assert f"'{out}' is being written by simtest generate (pid {holder.pid}, started " in proc.stderr
        assert "wait for it, or choose another --out" in proc.stderr
        assert not out.exists()  # refused before any work: nothing written
        assert took < 30
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    assert lock_path(out).exists()  # the killed holder's file stays, but the kernel released its lock
    proc = subprocess.run([*SIMTEST, *GEN, "--scenes", "1", "--out", str(out)], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert not lock_path(out).exists()  # released and removed at the end of the run
    assert sorted(p.name for p in tmp_path.iterdir()) == ["ds"]


def test_two_generate_runs_on_one_folder_one_is_refused_and_the_other_completes(tmp_path):
    out = tmp_path / "ds"
    first = subprocess.Popen([*SIMTEST, *GEN, "--scenes", "40", "--out", str(out)], stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while not lock_path(out).exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    second = subprocess.run([*SIMTEST, *GEN, "--scenes", "1", "--out", str(out), "--overwrite"], capture_output=True,
                            text=True)
    _, err = first.communicate(timeout=600)
    assert first.returncode == 0, err
    assert second.returncode == 2 and "is being written by simtest generate" in second.stderr
    assert len([p for p in (out / "train_pbr").iterdir() if not p.name.startswith(".")]) == 40


@pytest.mark.parametrize("argv", [
    ["eval", "--estimator", "oracle", "--data", "{data}", "--out", "{out}"],
    ["corrupt", "--in", "{data}", "--weather", "fog", "--out", "{out}"],
    ["grasp", "--episodes", "1", "--estimator", "oracle", "--out", "{out}"],
    ["sweep", "{config}", "--out", "{out}"],
    ["train", "segmentation", "--data", "{data}", "--out", "{out}"],
    ["demo", "--out", "{out}"],
    ["objects", "export", "--set", "builtin-small", "--out", "{out}"],
])
def test_every_command_that_writes_a_folder_holds_its_lock(argv, tmp_path, small_dataset):
    out = tmp_path / "out"
    config = tmp_path / "sweep.toml"
    config.write_text('[[estimators]]\nname = "o"\nestimator = "oracle"\n[dataset]\npath = "x"\n')
    holder = _hold(out)
    try:
        args = [a.format(data=small_dataset, out=out, config=config) for a in argv]
        proc = subprocess.run([*SIMTEST, *args], capture_output=True, text=True, timeout=120)
    finally:
        holder.send_signal(signal.SIGKILL)
        holder.wait()
    assert proc.returncode == 2 and "is being written by simtest generate" in proc.stderr, proc.stderr
    assert not out.exists()


def test_the_lock_is_exclusive_within_one_process_too_and_names_the_holder(tmp_path):
    with output_lock(tmp_path / "a" / "b", "simtest eval"):
        with pytest.raises(OutputBusyError, match=r"is being written by simtest eval \(pid \d+, started"):
            with output_lock(tmp_path / "a" / "b", "simtest eval"):
                pass
        with output_lock(tmp_path / "a" / "c", "simtest eval"):  # another folder: its own lock
            pass
    assert not (tmp_path / "a").exists()  # the parent made for the lock file is removed again


BAD_ESTIMATOR = "class Bad:\n    def estimate(self, obs):\n        raise RuntimeError('boom on purpose')\n"


def test_estimator_failures_print_one_traceback_and_a_summary(tmp_path, small_dataset):
    est = tmp_path / "bad.py"
    est.write_text(BAD_ESTIMATOR)
    base = [*SIMTEST, "eval", "--data", str(small_dataset), "--estimator", f"{est}:Bad", "--no-vsd"]
    proc = subprocess.run([*base, "--out", str(tmp_path / "e1")], capture_output=True, text=True)
    assert proc.returncode == 1
    assert proc.stderr.count("Traceback (most recent call last)") == 1
    # the first failure, its traceback (source line and last line) and the summary; not once per image
    assert proc.stderr.count("boom on purpose") == 4
    assert "the estimator failed on 6 of 6 images (exception 6)" in proc.stderr and "failures.csv" in proc.stderr
    verbose = subprocess.run([*base, "-v", "--out", str(tmp_path / "e2")], capture_output=True, text=True)
    assert verbose.stderr.count("Traceback (most recent call last)") == 1
    assert verbose.stderr.count("simtest: info: estimator failed on scene") == 5
    quiet = subprocess.run([*base, "--quiet", "--out", str(tmp_path / "e3")], capture_output=True, text=True)
    assert quiet.stderr.strip().splitlines() == [
        l for l in quiet.stderr.strip().splitlines() if l.startswith("simtest eval: error: the estimator failed")]


def _mount_tmpfs(path: Path, size: str) -> bool:
    path.mkdir(parents=True, exist_ok=True)
    if shutil.which("mount") is None or os.geteuid() != 0:
        return False
    return subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size}", "tmpfs", str(path)],
                          capture_output=True).returncode == 0


def test_a_full_disk_names_the_scene_the_free_space_and_resume_gives_the_same_bytes(tmp_path):
    disk = tmp_path / "disk"
    if not _mount_tmpfs(disk, "700k"):
        pytest.skip("a small tmpfs cannot be mounted here (needs root and mount)")
    try:
        argv = [*SIMTEST, *GEN, "--scenes", "4", "--width", "320", "--height", "240"]
        proc = subprocess.run([*argv, "--out", str(disk / "ds")], capture_output=True, text=True)
        assert proc.returncode == 2
        err = proc.stderr.strip()
        assert "error: no space left on device while writing " + str(disk / "ds" / "train_pbr") in err, err
        assert err.endswith("free); free space and rerun with --resume"), err
        assert not [p for p in (disk / "ds" / "train_pbr").iterdir() if p.name.endswith(".partial")]
        subprocess.run(["mount", "-o", "remount,size=64m", str(disk)], check=True)
        proc = subprocess.run([*argv, "--out", str(disk / "ds"), "--resume"], capture_output=True, text=True)
        assert proc.returncode == 0, proc.stderr
        proc = subprocess.run([*argv, "--out", str(tmp_path / "whole")], capture_output=True, text=True)
        assert proc.returncode == 0, proc.stderr
        split_a, split_b = disk / "ds" / "train_pbr", tmp_path / "whole" / "train_pbr"
        files = sorted(p.relative_to(split_b) for p in split_b.rglob("*") if p.is_file())
        assert files == sorted(p.relative_to(split_a) for p in split_a.rglob("*") if p.is_file())
        assert all((split_a / f).read_bytes() == (split_b / f).read_bytes() for f in files)
    finally:
        subprocess.run(["umount", str(disk)], capture_output=True)
