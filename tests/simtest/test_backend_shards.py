"""``simtest eval`` and ``simtest corrupt`` in parallel: one worker, a local pool of two and two Ray workers
write the same files (the measured times excepted); estimator faults inside a Ray worker land in failures.csv."""

from __future__ import annotations

import csv
import json
import re
from pathlib import Path

import pytest

from simtest.backend import Backend, RunStats
from simtest.cli import main
from simtest.corrupt import CorruptionSpec, corrupt_dataset
from simtest.errors import ConfigError, EstimatorError
from simtest.evaluation.run import evaluate

#: An estimator with a fault of each kind on given images (loaded by path in the workers).
FAULTY = '''
import sys
import time


class Faulty:
    def estimate(self, observation):
        if (observation.scene_id, observation.im_id) == (0, 1):
            raise RuntimeError("broken on purpose")
        if (observation.scene_id, observation.im_id) == (1, 0):
            sys.exit(4)
        if (observation.scene_id, observation.im_id) == (2, 1):
            time.sleep(30)
        return []
'''

BACKENDS = {"local-1": Backend("local", 1), "local-2": Backend("local", 2), "ray-2": Backend("ray", 2)}


@pytest.fixture(scope="module")
def shards_dataset(tmp_path_factory, small_config):
    """3 scenes x 2 frames at 128x96."""
    from simtest.generators.pipeline import generate

    out = tmp_path_factory.mktemp("shards") / "ds"
    generate(small_config.replace(**{"scenes": 3, "frames_per_scene": 2, "camera.width": 128,
                                     "camera.height": 96}), out, progress=False)
    return out


@pytest.fixture(scope="module")
def local_ray():
    ray = pytest.importorskip("ray")
    ray.init(num_cpus=2, include_dashboard=False, logging_level="WARNING")
    yield ray
    ray.shutdown()


def _eval_files(out: Path) -> dict[str, str]:
    """The texts of an eval folder with the measured times (results.csv ``time``, metrics.json
    ``*_time_per_image_s``, the time in metrics.md) and the run's back end and workers blanked."""
    texts = {p.name: p.read_text() for p in sorted(out.iterdir())}
    texts["results.csv"] = "\n".join(line.rsplit(",", 1)[0] for line in texts["results.csv"].splitlines())
    texts["metrics.json"] = re.sub(r'("(mean|median)_time_per_image_s": )[^,\n]+', r"\1T", texts["metrics.json"])
    texts["metrics.json"] = re.sub(r'("backend": "\w+",\s*"workers": )\d+', r'"backend": B, "workers": W',
                                   texts["metrics.json"])
    texts["metrics.md"] = re.sub(r"time per image: mean [^ ]+ s", "time per image: T", texts["metrics.md"])
    return texts


@pytest.mark.parametrize("estimator,options", [("oracle", {"rot_noise_deg": 5.0, "drop_rate": 0.3}),
                                               ("icp", {"coarse_rotations": 60, "refine_top": 1})])
def test_eval_output_does_not_depend_on_workers_or_backend(shards_dataset, local_ray, tmp_path, estimator,
                                                           options):
    outputs = {}
    for name, backend in BACKENDS.items():
        stats = RunStats()
        report = evaluate(shards_dataset, estimator, estimator_options=options, vsd=False, progress=False,
                          out_dir=tmp_path / name, backend=backend, stats=stats)
        assert stats.finished == 3 and stats.backend == backend.name  # one unit per scene
        assert report.settings["backend"] == backend.name and report.settings["workers"] == backend.workers
        outputs[name] = _eval_files(tmp_path / name)
    assert outputs["local-1"]["results.csv"].count("\n") > 3
    assert outputs["local-2"] == outputs["local-1"]
    assert outputs["ray-2"] == outputs["local-1"]


def test_estimator_faults_in_ray_workers_land_in_failures_csv(shards_dataset, local_ray, tmp_path):
    plugin = tmp_path / "faulty.py"
    plugin.write_text(FAULTY)
    spec = f"{plugin}:Faulty"
    for name in ("local-1", "ray-2"):
        report = evaluate(shards_dataset, spec, vsd=False, progress=False, timeout=0.5, out_dir=tmp_path / name,
                          backend=BACKENDS[name])
        assert report.num_failed_images == 3
    with open(tmp_path / "ray-2" / "failures.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert [(r["scene_id"], r["im_id"], r["kind"]) for r in rows] == [
        ("0", "1", "exception"), ("1", "0", "exit"), ("2", "1", "timeout")]
    assert "broken on purpose" in rows[0]["message"] and "faulty.py" in rows[0]["traceback"]
    assert (tmp_path / "ray-2" / "failures.csv").read_bytes() == (tmp_path / "local-1" / "failures.csv").read_bytes()
    with pytest.raises(EstimatorError, match=r"failed on scene \d image \d \((exception|exit)\)"):
        evaluate(shards_dataset, spec, vsd=False, progress=False, timeout=0.5, fail_fast=True,
                 backend=BACKENDS["ray-2"])


def test_an_instance_that_cannot_be_sent_to_workers_is_a_config_error(shards_dataset):
    def local_fn(observation):
        return []

    with pytest.raises(ConfigError, match="cannot be sent to worker processes"):
        evaluate(shards_dataset, local_fn, vsd=False, progress=False, backend=BACKENDS["local-2"])


def _tree(root: Path) -> dict[str, bytes]:
    """Every file under ``root`` by relative path; corruption.json without its ``execution`` record."""
    files = {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}
    record = json.loads(files.pop("corruption.json"))
    record.pop("execution")
    files["corruption.json"] = json.dumps(record).encode()
    return files


def test_corrupt_output_does_not_depend_on_workers_or_backend(shards_dataset, local_ray, tmp_path):
    spec = CorruptionSpec(weather="fog", severity=3, occlusion="L2", depth_noise="kinect-v1")
    trees = {}
    for name, backend in BACKENDS.items():
        stats = RunStats()
        record = corrupt_dataset(shards_dataset, tmp_path / name, spec, seed=5, progress=False, backend=backend,
                                 stats=stats)
        assert stats.finished == 3
        assert record["execution"] == {"backend": backend.name, "workers": backend.workers}
        trees[name] = _tree(tmp_path / name)
    assert trees["local-2"] == trees["local-1"]
    assert trees["ray-2"] == trees["local-1"]
    clean = _tree_plain(shards_dataset)
    changed = {k for k in clean if trees["local-1"][k] != clean[k]}
    assert any("/rgb/" in k for k in changed) and any("/depth/" in k for k in changed)
    assert any(k.endswith("scene_gt_info.json") for k in changed)


def _tree_plain(root: Path) -> dict[str, bytes]:
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


def test_cli_runs_on_ray_and_prints_the_run_summary(shards_dataset, local_ray, tmp_path, capsys):
    rc = main(["corrupt", "--in", str(shards_dataset), "--out", str(tmp_path / "fog"), "--weather", "fog",
               "--seed", "5", "--workers", "2", "--backend", "ray"])
    assert rc == 0
    assert "simtest corrupt: ray: 3 units done, 0 retried, 0 failed" in capsys.readouterr().err
    rc = main(["eval", "--data", str(tmp_path / "fog"), "--estimator", "oracle", "--out", str(tmp_path / "ev"),
               "--no-vsd", "--workers", "2", "--backend", "ray"])
    captured = capsys.readouterr()
    assert rc == 0 and "simtest eval: ray: 3 units done, 0 retried, 0 failed" in captured.err
    settings = json.loads((tmp_path / "ev" / "metrics.json").read_text())["settings"]
    assert settings["backend"] == "ray" and settings["workers"] == 2
    rc = main(["eval", "--data", str(tmp_path / "fog"), "--estimator", "oracle", "--out", str(tmp_path / "ev2"),
               "--ray-address", "auto"])
    assert rc == 2 and "ray_address 'auto' needs backend 'ray'" in capsys.readouterr().err
