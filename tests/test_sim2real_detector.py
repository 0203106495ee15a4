"""docs/sim2real_detector.py on a generated dataset: the candidate regions the template stage poses, with and
without ``--extra``, and the per-object counts adding up to the whole."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
DETECTOR = ROOT / "simtest" / "estimators" / "weights" / "keypoints_detector_builtin-small_320x240.onnx"


def _run(small_dataset: Path, *extra: str) -> str:
    done = subprocess.run([sys.executable, str(ROOT / "docs" / "sim2real_detector.py"), str(DETECTOR),
                           str(small_dataset), "--max-images", "3", "--threads", "1", "--per-object", *extra],
                          capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-2000:]
    return done.stdout


def _count(out: str, rule: str) -> tuple[int, int]:
    held, n = re.search(rf"^{rule}\s+(\d+)/(\d+) = ", out, re.M).groups()
    return int(held), int(n)


def test_extra_regions_hold_at_least_as_many_targets_from_more_candidates(small_dataset):
    plain, extra = _run(small_dataset), _run(small_dataset, "--extra", "0.05")
    (c0, n), (c1, n1) = _count(plain, "cands"), _count(extra, "cands")
    assert n == n1 > 0 and c0 <= c1 <= n
    assert _count(plain, "prob3") == _count(extra, "prob3")  # the rules of the class map are untouched

    def mean(out: str) -> float:
        return float(re.search(r"candidate regions per object and image: ([\d.]+)", out).group(1))

    assert 0 < mean(plain) < mean(extra)
    for out in (plain, extra):
        rows = re.findall(r"^object (\d+): (\d+) targets, prob3 (\d+), cands (\d+)$", out, re.M)
        assert sum(int(r[1]) for r in rows) == n
        assert sum(int(r[3]) for r in rows) == _count(out, "cands")[0]
        assert all(int(r[2]) <= int(r[1]) and int(r[3]) <= int(r[1]) for r in rows)
