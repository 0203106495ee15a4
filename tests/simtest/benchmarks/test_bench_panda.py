"""``simtest bench panda``: the Panda model's speed figures and one scripted grasp, with real MuJoCo physics."""

from __future__ import annotations

import pytest

from simtest.benchmarks.panda import benchmark
from simtest.cli import main
from simtest.errors import ConfigError


def test_bench_panda_prints_every_figure_and_the_grasp_succeeds(capsys):
    assert main(["bench", "panda", "--steps", "50", "--quiet"]) == 0
    lines = dict(line.split(": ") for line in capsys.readouterr().out.strip().splitlines())
    assert set(lines) == {"steps_per_s", "realtime_factor", "steps_per_s_moving", "grasp_wall_s", "grasp_sim_s",
                          "grasp_success"}
    assert float(lines["grasp_success"]) == 1.0
    assert float(lines["grasp_sim_s"]) > 1.0  # includes the 1 s hold


def test_bench_panda_names_the_bad_step_count():
    with pytest.raises(ConfigError, match=r"n_steps must be >= 25 .* got 3"):
        benchmark(3)
