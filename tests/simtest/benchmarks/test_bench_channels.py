"""`simtest bench channels`: every dense channel is timed on real rendered sequence views."""

from __future__ import annotations

from simtest.benchmarks.channels import bench_channels
from simtest.cli import main


def test_every_channel_gets_a_cost(capsys):
    res = bench_channels(64, 48, scenes=1, views=2, objects="builtin-small")
    assert res["frames"] == 2
    assert set(res["ms_per_frame"]) == {"annotation", "instances", "coords", "normals", "flow", "keypoints"}
    assert all(ms > 0 for ms in res["ms_per_frame"].values())
    assert main(["bench", "channels", "--width", "64", "--height", "48", "--scenes", "1", "--frames-per-scene", "2",
                 "--objects", "builtin-small"]) == 0
    out = capsys.readouterr().out
    assert "| normals |" in out and "| flow |" in out


def test_bench_stereo_reports_the_sensor_against_the_fast_frame(capsys):
    assert main(["bench", "stereo", "--width", "80", "--height", "60", "--views", "1"]) == 0
    out = capsys.readouterr().out
    assert "d435-stereo, 80x60" in out and "fast frame" in out and "valid" in out
