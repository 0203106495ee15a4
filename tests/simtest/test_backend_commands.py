"""generate, grasp and sweep on Ray give the local back end's outputs: the same bytes for every scene file, the
same episode rows, the same sweep tables; a killed Ray run resumes to an uninterrupted local run's bytes; a
dataset made before the back-end fields existed still resumes."""

from __future__ import annotations

import csv
import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from simtest.envs.runner import GraspRunConfig, run_grasp_episodes
from simtest.errors import ConfigError, DatasetError
from simtest.generators.config import GenerateConfig
from simtest.generators.pipeline import generate

#: Columns of episodes.csv that measure time, not outcome.
TIMING = ("wall_s", "estimate_s")


@pytest.fixture(scope="module")
def local_ray():
    """One local Ray instance for the module (simtest's own unit functions need no PYTHONPATH set-up)."""
    ray = pytest.importorskip("ray")
    ray.init(address="local", num_cpus=2, include_dashboard=False, logging_level="WARNING")
    yield ray
    ray.shutdown()


@pytest.fixture(scope="module")
def tiny(small_config) -> GenerateConfig:
    return small_config.replace(**{"scenes": 3, "frames_per_scene": 2, "camera.width": 128, "camera.height": 96})


@pytest.fixture(scope="module")
def local_dataset(tmp_path_factory, tiny) -> Path:
    out = tmp_path_factory.mktemp("local") / "d"
    generate(tiny, out, progress=False)
    return out


def _digest(root: Path) -> dict[str, str]:
    """sha1 of every file under ``root`` except the manifest (it records the command line and back end)."""
    return {str(p.relative_to(root)): hashlib.sha1(p.read_bytes()).hexdigest() for p in sorted(root.rglob("*"))
            if p.is_file() and p.name != "manifest.json"}


def _manifest(root: Path) -> dict:
    return json.loads((root / "manifest.json").read_text())


def test_generate_on_ray_writes_the_local_bytes(local_ray, tmp_path, tiny, local_dataset):
    rep = generate(tiny.replace(backend="ray", workers=2), tmp_path / "r", progress=False)
    assert rep.scenes_done == 3 and rep.run.backend == "ray" and rep.run.finished == 3
    ref = _digest(local_dataset)
    assert len(ref) > 30 and _digest(tmp_path / "r") == ref
    runs = _manifest(tmp_path / "r")["runs"]
    assert runs == [{**runs[0], "backend": "ray", "scenes_made": 3, "retried": 0, "lost": []}]
    assert _manifest(local_dataset)["runs"][0]["backend"] == "local"


def test_killed_ray_generate_resumes_to_the_local_bytes(local_ray, tmp_path, tiny):
    cfg = tiny.replace(scenes=6)
    ref = tmp_path / "ref"
    generate(cfg, ref, progress=False)
    config = tmp_path / "tiny.toml"
    config.write_text(cfg.to_toml())
    out = tmp_path / "killed"
    cmd = [sys.executable, "-m", "simtest", "generate", "--config", str(config), "--backend", "ray",
           "--workers", "1", "--out", str(out), "--quiet"]
    mark = f"killed-{os.getpid()}-{time.time_ns()}"  # finds the killed run's Ray workers (they inherit it)
    proc = subprocess.Popen(cmd, env={**os.environ, "SIMTEST_TEST_RUN": mark}, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL, start_new_session=True)
    split = out / "train_pbr"
    deadline = time.time() + 180
    while time.time() < deadline and proc.poll() is None:
        if split.is_dir() and any(p.name == "000000" for p in split.iterdir()):
            break
        time.sleep(0.01)
    os.killpg(proc.pid, signal.SIGKILL)  # the driver and the local Ray instance it started
    proc.wait()
    # its workers leave once they notice their node is gone (one may finish the scene it is making first)
    while time.time() < deadline and _processes_marked(mark):
        time.sleep(0.2)
    done_before = sorted(p.name for p in split.iterdir() if not p.name.startswith("."))
    assert 1 <= len(done_before) < 6, f"the run was not killed mid-way: {done_before}"
    rep = generate(cfg.replace(backend="ray", workers=2), out, resume=True, progress=False)
    assert rep.scenes_skipped == len(done_before) and rep.scenes_done == 6 - len(done_before)
    assert _digest(out) == _digest(ref)
    assert not list(split.glob(".*"))


def _processes_marked(mark: str) -> list[int]:
    """Process ids whose environment holds ``SIMTEST_TEST_RUN=mark``."""
    found = []
    for env in Path("/proc").glob("[0-9]*/environ"):
        try:
            if f"SIMTEST_TEST_RUN={mark}".encode() in env.read_bytes().split(b"\0"):
                found.append(int(env.parent.name))
        except OSError:
            continue
    return found


def test_resume_ignores_where_it_runs_and_new_fields_at_their_defaults(tmp_path, tiny):
    out = tmp_path / "d"
    cfg = tiny.replace(scenes=2)
    generate(cfg, out, progress=False)
    manifest = _manifest(out)
    for key in ("backend", "ray_address", "captions"):  # as written before these fields existed
        del manifest["config"][key]
    (out / "manifest.json").write_text(json.dumps(manifest))
    shutil.rmtree(out / "train_pbr" / "000001")
    rep = generate(cfg.replace(workers=2), out, resume=True, progress=False)
    assert rep.scenes_done == 1 and rep.scenes_skipped == 1
    # an absent field whose new value is not its default is a change; where it runs never is
    with pytest.raises(DatasetError, match=r"at captions \(False -> True\); use"):
        generate(cfg.replace(captions=True, backend="ray"), out, resume=True, progress=False)


def test_backend_settings_are_checked_in_every_config():
    with pytest.raises(ConfigError, match="ray_address 'auto' needs backend 'ray'"):
        GenerateConfig().replace(ray_address="auto")
    with pytest.raises(ConfigError, match=r"backend = 'dask' is invalid; allowed: 'local' \| 'ray'"):
        GenerateConfig().replace(backend="dask")
    with pytest.raises(ConfigError, match="backend must be one of local, ray"):
        run_grasp_episodes(GraspRunConfig(backend="spark", episodes=1), progress=False)
    from simtest.sweeps.grid import SweepConfig

    with pytest.raises(ConfigError, match="ray_address 'h:1' needs backend 'ray'"):
        SweepConfig.from_dict({"estimators": [{"name": "o", "estimator": "oracle"}],
                               "dataset": {"path": "x"}, "ray_address": "h:1"})


def _rows(path: Path) -> list[dict]:
    with path.open(newline="") as f:
        return [{k: v for k, v in r.items() if k not in TIMING} for r in csv.DictReader(f)]


def _timing(metric: str | None) -> bool:
    """Whether a summary metric measures time (seconds), not outcome."""
    return bool(metric) and metric.endswith("_s") and any(w in metric for w in ("time", "wall", "estimate"))


def test_grasp_on_ray_gives_the_local_episodes(local_ray, tmp_path):
    cfg = GraspRunConfig(estimator="oracle", episodes=2, seed=3, objects="builtin-small", width=96, height=72)
    run_grasp_episodes(cfg, tmp_path / "local", progress=False)
    rep = run_grasp_episodes(GraspRunConfig(**{**cfg.__dict__, "backend": "ray", "workers": 2}), tmp_path / "ray",
                             progress=False)
    local, ray_rows = _rows(tmp_path / "local" / "episodes.csv"), _rows(tmp_path / "ray" / "episodes.csv")
    assert len(local) == 2 and ray_rows == local
    run = json.loads((tmp_path / "ray" / "summary.json").read_text())["run"]
    assert run["backend"] == "ray" and run["lost_episodes"] == [] and rep.run.finished == 2


def test_sweep_on_ray_gives_the_local_tables(local_ray, tmp_path):
    from simtest.sweeps.grid import SweepConfig, run_sweep

    data = {"seed": 1, "estimators": [{"name": "oracle", "estimator": "oracle", "options": {"rot_noise_deg": 2.0}}],
            "dataset": {"generate": {"objects": "builtin-small", "scenes": 2, "frames_per_scene": 2,
                                     "camera": {"width": 96, "height": 72}}},
            "factors": {"occlusion": [], "corruptions": ["fog"], "severities": [3], "depth_noise": []},
            "grasp": {"episodes": 2, "width": 96, "height": 72}}
    run_sweep(SweepConfig.from_dict(data), tmp_path / "local", progress=False)
    rep = run_sweep(SweepConfig.from_dict({**data, "backend": "ray", "workers": 2}), tmp_path / "ray",
                    progress=False)
    assert sorted(rep.cells_run) == ["oracle/clean/grasp", "oracle/clean/pose", "oracle/fog-3/grasp",
                                     "oracle/fog-3/pose"]
    for name in ("results.csv", "summary.csv"):
        ref = [r for r in _rows(tmp_path / "local" / name) if not _timing(r.get("metric"))]
        got = [r for r in _rows(tmp_path / "ray" / name) if not _timing(r.get("metric"))]
        assert got == ref and len(ref) > 4, name
    made = {k: v for k, v in _digest(tmp_path / "ray" / "data").items() if not k.endswith("corruption.json")}
    assert made == {k: v for k, v in _digest(tmp_path / "local" / "data").items()
                    if not k.endswith("corruption.json")}  # it records the path of its source
    # where a sweep runs is not part of its config: a local resume of the Ray sweep reuses every cell
    again = run_sweep(SweepConfig.from_dict(data), tmp_path / "ray", resume=True, progress=False)
    assert again.cells_run == [] and len(again.cells_skipped) == 4


def test_objects_prepare_on_ray_gives_the_local_parts(local_ray):
    """``simtest objects prepare --backend ray``: one Ray task per object, the same collision parts as locally
    (the workers read and fill the cache the instance was started with)."""
    from simtest.backend import Backend, RunStats
    from simtest.objects.prepare import prepare_objects

    local = prepare_objects("builtin-small", progress=False)
    stats = RunStats()
    ray_rows = prepare_objects("builtin-small", backend=Backend("ray", 2), progress=False, stats=stats)
    assert [(r.obj_id, r.name, r.parts) for r in ray_rows] == [(r.obj_id, r.name, r.parts) for r in local]
    assert {r.collision for r in ray_rows} <= {"hull", "cached"}  # the local run above filled the cache
    assert stats.backend == "ray" and stats.finished == len(local) == 4
