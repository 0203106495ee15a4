"""docs/sim2real_annotation_edges.py on a generated dataset: exact annotations need no depth change to put
their outlines on the image's edges; annotations moved 6 % farther along their rays are found too far (the
check recovers most of the 6 %: 4-5 % on these small images)."""

from __future__ import annotations

import json
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def _run(data: Path, out: Path) -> list[dict]:
    done = subprocess.run([sys.executable, str(ROOT / "docs" / "sim2real_annotation_edges.py"), str(data),
                           "--min-visible", "0.8", "--json", str(out)], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    assert "| object | targets | depth factor" in done.stdout
    return json.loads(out.read_text())


def test_depth_factor_of_exact_and_moved_annotations(small_config, tmp_path):
    from simtest.generators.pipeline import generate

    data = tmp_path / "clean"  # 320x240 and no distractors: enough outline pixels for the edge fit
    generate(small_config.replace(**{"scenes": 1, "camera.width": 320, "camera.height": 240,
                                     "scene.distractors": [0, 0]}), data, progress=False)
    exact = _run(data, tmp_path / "exact.json")
    assert len(exact) >= 6
    assert abs(float(np.median([r["scale"] for r in exact])) - 1.0) <= 0.01

    moved = tmp_path / "moved"
    shutil.copytree(data, moved)
    for gt_file in moved.glob("*/*/scene_gt.json"):
        gt = json.loads(gt_file.read_text())
        for instances in gt.values():
            for inst in instances:
                inst["cam_t_m2c"] = [1.06 * v for v in inst["cam_t_m2c"]]  # millimetres, as BOP stores them
        gt_file.write_text(json.dumps(gt))
    found = _run(moved, tmp_path / "moved.json")
    assert len(found) == len(exact)
    # the outline is drawn 1/1.06 as large: the edges want the pose back toward 1/1.06 = 0.943 of its depth
    assert 0.925 <= float(np.median([r["scale"] for r in found])) <= 0.975
