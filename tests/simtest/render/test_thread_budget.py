"""Thread budget of rendering workers (llvmpipe, image writers, OpenCV) and the generate benchmark's report."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import cv2
import numpy as np
import pytest

from simtest.backend.threads import ThreadBudget, available_cores, thread_budget
from simtest.io.bop import SceneWriter, _png, encode_depth


@pytest.mark.parametrize("workers, cores, expected", [
    (1, 2, ThreadBudget(cores=2, llvmpipe=2, writers=2, opencv=2)),
    (2, 2, ThreadBudget(cores=1, llvmpipe=0, writers=1, opencv=1)),
    (3, 2, ThreadBudget(cores=1, llvmpipe=0, writers=1, opencv=1)),  # more workers than cores: at least 1 each
    (2, 8, ThreadBudget(cores=4, llvmpipe=4, writers=2, opencv=4)),
    (0, 1, ThreadBudget(cores=1, llvmpipe=0, writers=1, opencv=1)),
])
def test_thread_budget_splits_the_cores_between_workers(workers, cores, expected):
    assert thread_budget(workers, cores) == expected


def test_thread_budget_defaults_to_the_cores_this_process_may_use():
    assert thread_budget(1) == thread_budget(1, available_cores())
    assert 1 <= available_cores() <= (os.cpu_count() or 1)


def _budget_in_fresh_process(env: dict[str, str]) -> dict:
    code = ("import json, cv2, os; from simtest.backend.threads import apply_thread_budget; b = apply_thread_budget(2, 2); "
            "print(json.dumps({'lp': os.environ['LP_NUM_THREADS'], 'llvmpipe': b.llvmpipe, "
            "'cv2': cv2.getNumThreads()}))")
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_apply_thread_budget_sets_llvmpipe_and_opencv_threads_but_keeps_the_users_choice():
    env = {k: v for k, v in os.environ.items() if k != "LP_NUM_THREADS"}
    assert _budget_in_fresh_process(env) == {"lp": "0", "llvmpipe": 0, "cv2": 1}
    assert _budget_in_fresh_process({**env, "LP_NUM_THREADS": "3"}) == {"lp": "3", "llvmpipe": 3, "cv2": 1}


def test_writer_threads_write_the_bytes_of_the_encoders(tmp_path):
    """Masks (bool or 0/1 integers) and depth are converted on the writer threads into the same PNG bytes."""
    rng = np.random.default_rng(0)
    depth = rng.uniform(0.3, 2.0, (24, 32)).astype(np.float32)
    depth[:3] = 0.0
    mask = np.zeros((24, 32), dtype=bool)
    mask[5:15, 7:20] = True
    from simtest.camera import CameraModel
    from simtest.geometry import Pose

    cam = CameraModel(np.array([[30.0, 0, 16], [0, 30.0, 12], [0, 0, 1]]), 32, 24).with_pose(Pose.identity())
    rgb = rng.integers(0, 256, (24, 32, 3), dtype=np.uint8)
    w = SceneWriter(tmp_path, 0, rgb_format="png", threads=1)

    class Inst:
        obj_id, T_cam_obj = 1, Pose(np.eye(3), np.array([0.0, 0.0, 1.0]))
        bbox_obj = bbox_visib = [7, 5, 12, 9]
        px_count_all = px_count_valid = px_count_visib = 130
        visib_fract = 1.0

    w.add(0, rgb, depth, cam, [Inst()], [mask], [mask.astype(np.int64)])
    scene = w.close()
    want_mask = _png(mask.astype(np.uint8) * 255, True)
    assert (scene / "mask" / "000000_000000.png").read_bytes() == want_mask
    assert (scene / "mask_visib" / "000000_000000.png").read_bytes() == want_mask
    assert (scene / "depth" / "000000.png").read_bytes() == _png(encode_depth(depth, 0.1))
    back = cv2.imread(str(scene / "rgb" / "000000.png"), cv2.IMREAD_UNCHANGED)
    assert np.array_equal(back[..., ::-1], rgb)


def test_bench_generate_reports_ratios_cpu_time_and_worker_efficiency(capsys):
    from simtest.cli import main

    assert main(["bench", "generate", "--width", "64", "--height", "48", "--objects", "builtin-small",
                 "--objects-per-scene", "2", "--scenes", "2", "--views", "2", "--quiet"]) == 0
    rows = {}
    for line in capsys.readouterr().out.strip().splitlines()[2:]:
        name, value = line.strip("|").rsplit("|", 1)
        rows[name.strip()] = value.strip()
    assert rows["scenes x views per scene"] == "2 x 2"
    assert float(rows["pipeline / raw"]) > 0
    assert float(rows["CPU ms per annotated frame, 1 worker (all threads)"]) > 0
    cores, ideal = rows["cores; ideal frames/s = cores / CPU s per frame"].split("; ")
    cpu = float(rows["CPU ms per annotated frame, 1 worker (all threads)"])
    assert float(ideal) == pytest.approx(int(cores) / (cpu / 1000), rel=0.01, abs=0.01)
    busy = float(rows["full pipeline, 2 workers, frames/s (busy time of the slower worker)"])
    assert float(rows["2 workers (busy) / ideal"]) == pytest.approx(busy / float(ideal), rel=0.02, abs=0.01)
    scene_work, with_start_up = rows["CPU ms per frame, 2 workers: scene work / with start-up and parent"].split(" / ")
    assert 0 < float(scene_work) <= float(with_start_up)
    assert float(rows["2 workers (busy) / (cores / their scene-work CPU s per frame)"]) == pytest.approx(
        busy * float(scene_work) / 1000 / int(cores), rel=0.02, abs=0.01)
    # Where the CPU time goes, by thread group (Linux's per-thread counters); the groups add up to the total.
    if not os.path.isdir("/proc/self/task"):
        return
    by_thread = rows["CPU ms per frame by thread, 1 worker (threads that ended between two reads: not attributed)"]
    parts = dict(part.rsplit(" ", 1) for part in by_thread.split(", "))
    assert {"rendering", "scene ahead"} <= set(parts) <= {
        "rendering", "annotation", "scene ahead", "writers", "llvmpipe", "other", "not attributed"}
    assert all(float(v) >= 0 for v in parts.values())
    assert sum(map(float, parts.values())) == pytest.approx(cpu, rel=0.15, abs=1.0)
