"""docs/pbr_ray_floor.py: the path tracer's rays cast alone through a real settled scene, at a small size."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]


def test_the_ray_floor_casts_the_path_tracers_rays_and_times_them(tmp_path):
    pytest.importorskip("mitsuba")
    out = tmp_path / "floor.json"
    done = subprocess.run([sys.executable, str(ROOT / "docs" / "pbr_ray_floor.py"), "--scenes", "1", "--views", "2",
                           "--spp", "2", "--size", "64x48", "--repeat", "1", "--json", str(out)],
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    rec = json.loads(out.read_text())
    assert rec["size"] == [64, 48] and rec["spp"] == 2 and rec["views"] == 1
    n = 64 * 48 * 2
    rays = rec["rays"]
    # every sample casts a camera ray; a shadow and a bounce ray leave every surface hit, the second bounce's
    # rays every surface the first bounce hit
    assert rays["camera"] == n
    assert 0 < rays["bounce_2"] == rays["shadow_2"] <= rays["bounce_1"] == rays["shadow_1"] <= n
    assert all(v > 0 for v in rec["rays_s"].values()) and rec["trace_s"] > 0
    assert abs(rec["floor_s"] - sum(rec["rays_s"].values())) < 1e-9
