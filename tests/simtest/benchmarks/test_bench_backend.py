"""``simtest bench backend`` runs end to end (tiny images; real generation on the local pool and a real local Ray)."""

from __future__ import annotations

import pytest


def test_bench_backend_reports_every_run_and_an_estimate():
    pytest.importorskip("ray")
    from simtest.benchmarks.backend import bench_backend

    res = bench_backend(width=64, height=48, scenes=2, frames_per_scene=1, objects="builtin-small",
                        runs=(("local", 1), ("ray", 2)))
    assert [(r.backend, r.workers) for r in res.rows] == [("local", 1), ("ray", 2)]
    assert all(r.frames == 2 and r.seconds > 0 for r in res.rows)
    assert res.rows[0].startup_s == 0 and res.rows[1].startup_s > 0
    assert res.cpu_s_per_frame > 0 and res.bytes_per_frame > 0
    table = res.table()
    assert "| ray | 2 |" in table and "1.00x" in table
