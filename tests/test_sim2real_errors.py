"""docs/sim2real_errors.py on a generated dataset: exact estimates pass with no image offset, an estimate moved
along its viewing ray lands on its object but off, one moved out of view lands off the image."""

from __future__ import annotations

import re
import subprocess
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

from simtest.evaluation.run import evaluate, score_results
from simtest.io.bop_results import read_bop_results, write_bop_results

ROOT = Path(__file__).resolve().parents[1]


def test_buckets_of_exact_and_moved_estimates(small_dataset, tmp_path):
    evaluate(small_dataset, "oracle", out_dir=tmp_path / "exact", max_images=2, vsd=False, progress=False)
    rows = read_bop_results(tmp_path / "exact" / "results.csv")
    first = (rows[0].scene_id, rows[0].im_id)
    same_image = [k for k, r in enumerate(rows) if (r.scene_id, r.im_id) == first]
    assert len(same_image) >= 2
    a, b = same_image[:2]
    rows[a] = replace(rows[a], t=rows[a].t * 1.3)  # along its ray: the same pixels, far too deep
    rows[b] = replace(rows[b], t=rows[b].t + np.array([50.0, 0.0, 0.0]))  # 50 m aside: out of view
    write_bop_results(tmp_path / "moved.csv", rows)
    score_results(tmp_path / "moved.csv", small_dataset, out_dir=tmp_path / "moved", max_images=2,
                  vsd=False, progress=False)

    def run(folder: Path, *extra: str) -> str:
        done = subprocess.run([sys.executable, str(ROOT / "docs" / "sim2real_errors.py"), str(folder),
                               str(small_dataset), *extra], capture_output=True, text=True, timeout=600)
        assert done.returncode == 0, done.stderr[-2000:]
        return done.stdout

    def total(out: str) -> list[int]:
        line = re.search(r"^\| all \| (\d+) \| (.*) \|$", out, re.M)
        return [int(line.group(1))] + [int(x) for x in re.findall(r"(\d+) \(", line.group(2))]

    exact = total(run(tmp_path / "exact"))
    n = exact[0]
    assert n > 2 and exact[1:] == [n, 0, 0, 0, 0, 0, 0]
    out = run(tmp_path / "moved", "--results", str(tmp_path / "moved.csv"))
    moved = total(out)
    assert moved[0] == n and sum(moved[1:]) == n
    assert moved[1] == n - 2 and moved[2] == 1 and moved[6] == 1  # pass; on it, turned < 15; off the image
    du, dv = (float(x) for x in re.search(r"du ([-+\d.]+) px, dv ([-+\d.]+) px", out).groups())
    assert abs(du) < 1e-6 and abs(dv) < 1e-6
    assert re.search(r"distance estimated / true 1\.0000 ", out)
