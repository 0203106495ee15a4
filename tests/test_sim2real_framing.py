"""docs/sim2real_framing.py on a generated dataset: every counted region gets one pose per start, and the summary
counts them."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_the_framing_starts_script_poses_each_region_from_each_start(small_dataset, tmp_path, monkeypatch):
    monkeypatch.setenv("SIMTEST_CACHE", str(tmp_path / "cache"))
    out = tmp_path / "framing.jsonl"
    done = subprocess.run([sys.executable, str(ROOT / "docs" / "sim2real_framing.py"), "--data", str(small_dataset),
                           "--max-images", "1", "--starts", "1,1.4", "--candidates", "1", "--out", str(out)],
                          capture_output=True, text=True, timeout=900)
    assert done.returncode == 0, done.stderr[-2000:]
    (image,) = [json.loads(line) for line in out.read_text().splitlines()]
    assert image["regions"], "the shipped detector finds objects of a generated image"
    for region in image["regions"]:
        assert 0.1 < region["cover"] <= 1.0 and [s["start"] for s in region["starts"]] == [1.0, 1.4]
        assert all(s["err_d"] >= 0 and 0 <= s["re"] <= 180 and s["te"] >= 0 for s in region["starts"])
    n = len(image["regions"])
    summary = done.stdout.splitlines()[-3:]
    assert [line.split()[1] for line in summary] == ["1", "1.4", "1,1.4"]
    assert all(f"of {n} regions" in line for line in summary)
