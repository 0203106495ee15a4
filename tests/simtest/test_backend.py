"""The unit runner: local in-process, a local spawn pool, and a real local Ray instance give the same results;
a Ray worker lost mid-unit is retried; a unit's own exception reaches the driver unchanged."""

from __future__ import annotations

import os
from pathlib import Path

import pytest

from simtest.backend import Backend, BackendError, RunStats, check_backend, run_units
from simtest.errors import ConfigError

_STATE: dict = {}


def _init(offset: int) -> None:
    _STATE["offset"] = offset


def _square_plus(unit: int) -> tuple[int, int]:
    return unit, unit * unit + _STATE.get("offset", 0)


def _die_once(unit: tuple[int, str]) -> int:
    """Kills its worker process the first time it runs unit 1 (a marker file remembers), like a lost node."""
    i, marker = unit
    if i == 1 and not os.path.exists(marker):
        Path(marker).write_text("died")
        os._exit(1)
    return i * 10


def _raise(unit: int) -> int:
    raise ConfigError(f"bad unit {unit}")


def test_backend_settings_are_checked():
    with pytest.raises(ConfigError, match="backend must be one of local, ray; got 'dask'"):
        Backend("dask")
    with pytest.raises(ConfigError, match="needs backend 'ray'"):
        Backend("local", address="auto")
    with pytest.raises(ConfigError, match="workers must be an integer >= 1; got 0"):
        Backend("local", workers=0)
    assert check_backend("ray", "auto", 2) == "ray"


def test_missing_cluster_is_one_clear_error():
    pytest.importorskip("ray")
    import ray

    if ray.is_initialized():
        pytest.skip("a Ray instance is already running in this process")
    with pytest.raises(BackendError, match="cannot join Ray at 127.0.0.1:1: nothing accepts connections there"):
        list(run_units(_square_plus, [1], Backend("ray", 1, address="127.0.0.1:1")))


def test_a_ray_client_address_without_ray_client_is_refused_before_any_output(tmp_path):
    """``ray://`` needs Ray Client (``ray[client]``: grpcio); without it the refusal names the extra, and
    generate writes nothing."""
    pytest.importorskip("ray")
    from ray._private.utils import get_ray_client_dependency_error

    from simtest.backend import preflight

    if get_ray_client_dependency_error() is None:
        pytest.skip("Ray Client is installed here")
    with pytest.raises(BackendError, match=r"ray://127.0.0.1:1: ray:// addresses need Ray Client.*"
                                           r"pip install 'ray\[client\]==.*HOST:PORT without ray://"):
        preflight(Backend("ray", 1, address="ray://127.0.0.1:1"))


def test_run_records_say_where_it_ran():
    joined = RunStats(backend="ray", finished=4, cluster="joined", address="h:6379", nodes=2, cluster_cpus=8,
                      startup_s=0.91)
    assert joined.summary() == "ray: 4 units done, 0 retried, 0 failed (joined h:6379 in 0.9 s: 2 nodes, 8 CPUs)"
    assert joined.record(5) == {"backend": "ray", "ray_address": "h:6379", "cluster": "joined", "nodes": 2,
                                "cluster_cpus": 8, "startup_s": 0.91}  # no workers: they did not apply
    started = RunStats(backend="ray", cluster="started", nodes=1, cluster_cpus=2, startup_s=3.0)
    assert started.record(2)["workers"] == 2 and "local Ray instance started in 3.0 s: 1 node, 2 CPUs" in \
        started.summary()
    assert RunStats().record(3) == {"backend": "local", "ray_address": None, "workers": 3}


def test_local_in_process_and_pool_agree():
    _init(0)
    inline = sorted(run_units(_square_plus, range(6), Backend("local", 1)))
    stats = RunStats()
    pooled = sorted(run_units(_square_plus, range(6), Backend("local", 2), init=_init, init_args=(0,),
                              stats=stats))
    assert inline == pooled == [(i, i * i) for i in range(6)]
    assert stats.finished == 6 and stats.retried == 0


def test_local_pool_retries_a_unit_whose_worker_died(tmp_path, caplog):
    """A worker process that dies without an exception (here os._exit; in life a native abort or the OOM killer)
    does not hang the run: its unit runs again on a new pool, the finished ones are kept."""
    stats = RunStats()
    units = [(i, str(tmp_path / "marker")) for i in range(4)]
    with caplog.at_level("WARNING"):
        out = sorted(run_units(_die_once, units, Backend("local", 2), stats=stats))
    assert out == [0, 10, 20, 30]
    assert stats.finished == 4 and 1 <= stats.retried <= 2 and not stats.failures  # unit 1, maybe its neighbour
    assert "lost its worker process" in caplog.text


def test_local_pool_gives_up_after_the_retries(tmp_path):
    stats = RunStats()
    got = []
    with pytest.raises(BackendError, match=r"1 unit\(s\) were lost with their workers more than 1 time"):
        for r in run_units(_die_once_always, [(0, ""), (1, ""), (2, "")], Backend("local", 2, retries=1),
                           stats=stats):
            got.append(r)
    assert sorted(got) == [0, 2] and len(stats.failures) == 1 and stats.failures[0].unit == (1, "")


def test_only_the_unit_whose_worker_dies_is_charged_however_often_it_shares_a_pool():
    """Units in flight beside one whose worker dies are not charged: a pool that broke holding several runs each
    again alone, so with one retry every other unit still finishes, whatever the timing."""
    stats = RunStats()
    got = []
    units = [(i, "") for i in range(8)]
    with pytest.raises(BackendError, match=r"^1 unit\(s\) were lost"):
        for r in run_units(_die_once_always, units, Backend("local", 2, retries=1), stats=stats):
            got.append(r)
    assert sorted(got) == [0, 2, 3, 4, 5, 6, 7] and [f.unit for f in stats.failures] == [(1, "")]


def _bad_init(offset: int) -> None:
    raise ConfigError(f"bad initialiser argument {offset}")


def test_local_pool_raises_the_initialisers_exception_as_it_is():
    with pytest.raises(ConfigError, match="bad initialiser argument 7"):
        list(run_units(_square_plus, [1, 2, 3], Backend("local", 2), init=_bad_init, init_args=(7,)))


def test_local_pool_passes_the_units_exception_through():
    with pytest.raises(ConfigError, match="bad unit"):
        list(run_units(_raise, [1, 2, 3], Backend("local", 2)))


@pytest.fixture(scope="module")
def local_ray():
    ray = pytest.importorskip("ray")
    # the workers import this module's unit functions by name
    here = str(Path(__file__).parent)
    ray.init(num_cpus=2, include_dashboard=False, logging_level="WARNING",
             runtime_env={"env_vars": {"PYTHONPATH": os.pathsep.join([here, os.environ.get("PYTHONPATH", "")])}})
    yield ray
    ray.shutdown()


def test_ray_gives_the_local_results_and_runs_the_initialiser(local_ray):
    stats = RunStats()
    out = sorted(run_units(_square_plus, list(range(6)), Backend("ray", 2), init=_init, init_args=(100,),
                           stats=stats))
    assert out == [(i, i * i + 100) for i in range(6)]
    assert stats.finished == 6 and stats.backend == "ray" and stats.cluster_cpus == 2
    assert "ray: 6 units done, 0 retried, 0 failed" in stats.summary()


def test_ray_retries_a_unit_whose_worker_died(local_ray, tmp_path, capsys):
    stats = RunStats()
    units = [(i, str(tmp_path / "marker")) for i in range(3)]
    out = sorted(run_units(_die_once, units, Backend("ray", 2), stats=stats))
    assert out == [0, 10, 20]
    assert stats.retried == 1 and not stats.failures
    assert "lost its worker" in capsys.readouterr().err


def test_ray_gives_up_after_the_retries(local_ray, tmp_path):
    stats = RunStats()
    units = [(0, ""), (1, "")]  # unit 1 kills its worker every time
    got = []
    with pytest.raises(BackendError, match=r"1 unit\(s\) were lost with their workers more than 1 time"):
        for r in run_units(_die_once_always, units, Backend("ray", 2, retries=1), stats=stats):
            got.append(r)
    assert got == [0] and stats.retried == 1 and len(stats.failures) == 1


def _die_once_always(unit: tuple[int, str]) -> int:
    if unit[0] == 1:
        os._exit(1)
    return unit[0]


def test_ray_passes_the_units_exception_through(local_ray):
    with pytest.raises(ConfigError, match="bad unit"):
        list(run_units(_raise, [1, 2], Backend("ray", 2)))


def test_an_unreachable_cluster_fails_before_any_output_is_written(tmp_path):
    """generate, eval and corrupt check the back end before they create or touch their output folder."""
    pytest.importorskip("ray")
    from simtest.corrupt.dataset import corrupt_dataset
    from simtest.corrupt.spec import CorruptionSpec
    from simtest.evaluation.run import evaluate
    from simtest.generators.config import GenerateConfig
    from simtest.generators.pipeline import generate

    far = Backend("ray", 1, address="127.0.0.1:1")
    cfg = GenerateConfig().replace(**{"objects": "builtin-small", "scenes": 1, "frames_per_scene": 1,
                                      "camera.width": 64, "camera.height": 48, "backend": "ray",
                                      "ray_address": "127.0.0.1:1"})
    with pytest.raises(BackendError, match="nothing accepts connections there"):
        generate(cfg, tmp_path / "data", progress=False)
    assert not (tmp_path / "data").exists()
    generate(cfg.replace(backend="local", ray_address=None), tmp_path / "data", progress=False)
    with pytest.raises(BackendError, match="127.0.0.1:1"):
        evaluate(tmp_path / "data", "oracle", progress=False, out_dir=tmp_path / "eval", backend=far)
    with pytest.raises(BackendError, match="127.0.0.1:1"):
        corrupt_dataset(tmp_path / "data", tmp_path / "fog", CorruptionSpec(weather="fog", severity=1), 0,
                        progress=False, backend=far)
    assert not (tmp_path / "eval").exists() and not (tmp_path / "fog").exists()
