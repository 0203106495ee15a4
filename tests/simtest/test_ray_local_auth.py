"""simtest's own local Ray instance leaves the process's Ray settings as it found them: a plain ``ray.init()``
afterwards starts, also on a machine without ``~/.ray/auth_token`` (a fresh HOME here)."""

from __future__ import annotations

import os

import pytest

from simtest.backend import Backend, run_units


def test_a_plain_ray_init_after_simtests_local_instance_needs_no_token(tmp_path, monkeypatch):
    ray = pytest.importorskip("ray")
    from simtest.backend.ray_cluster import release

    if ray.is_initialized():  # pragma: no cover - another module's instance still up
        pytest.skip("a Ray instance is already running in this process")
    monkeypatch.setenv("HOME", str(tmp_path))  # no ~/.ray/auth_token
    for key in [k for k in os.environ if k.startswith(("RAY_AUTH", "RAY_ADDRESS"))]:
        monkeypatch.delenv(key)
    try:
        assert sorted(run_units(abs, [-2, -1], Backend("ray", 1))) == [1, 2]
    finally:
        release()
    assert not any(k.startswith("RAY_AUTH") for k in os.environ)
    ray.init(num_cpus=1, include_dashboard=False, logging_level="ERROR")  # Ray's own defaults
    try:
        assert ray.get(ray.put(3)) == 3
    finally:
        ray.shutdown()
