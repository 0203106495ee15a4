"""The generate pipeline: determinism across workers, kill -9 + resume, settling, and clear errors."""

from __future__ import annotations

import hashlib
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import mujoco
import numpy as np
import pytest

from simtest.errors import ConfigError, DatasetError
from simtest.generators.config import GenerateConfig
from simtest.generators.pipeline import generate, prepare_scene
from simtest.generators.settle import body_radius, body_speed


def _digest(root: Path) -> dict[str, str]:
    """sha1 of every file under ``root`` except the manifest (it records the command line)."""
    out = {}
    for p in sorted(root.rglob("*")):
        if p.is_file() and p.name != "manifest.json":
            out[str(p.relative_to(root))] = hashlib.sha1(p.read_bytes()).hexdigest()
    return out


@pytest.fixture(scope="module")
def tiny_config(small_config):
    return small_config.replace(**{"scenes": 3, "frames_per_scene": 2, "camera.width": 96, "camera.height": 72})


def test_same_seed_same_bytes_with_1_or_2_workers(tmp_path, tiny_config):
    a = generate(tiny_config, tmp_path / "a", progress=False)
    generate(tiny_config.replace(workers=2), tmp_path / "b", progress=False)
    assert a.scenes_done == 3 and a.frames_written == 6
    da, db = _digest(tmp_path / "a"), _digest(tmp_path / "b")
    assert len(da) > 20 and da == db
    c = generate(tiny_config.replace(seed=8), tmp_path / "c", progress=False)
    assert c.frames_written == 6
    assert _digest(tmp_path / "c") != da


def test_resume_after_kill_equals_uninterrupted_run(tmp_path, tiny_config):
    cfg = tiny_config.replace(scenes=8)
    ref = tmp_path / "ref"
    generate(cfg, ref, progress=False)
    out = tmp_path / "killed"
    code = ("import sys; from simtest.generators.config import GenerateConfig; "
            "from simtest.generators.pipeline import generate; import json; "
            f"generate(GenerateConfig.from_dict(json.loads(sys.argv[1])), {str(out)!r}, progress=False)")
    import json

    proc = subprocess.Popen([sys.executable, "-c", code, json.dumps(cfg.to_dict())], env=dict(os.environ))
    deadline = time.time() + 120
    split = out / "train_pbr"
    while time.time() < deadline and proc.poll() is None:
        if split.is_dir() and any(p.name == "000000" for p in split.iterdir()):
            break
        time.sleep(0.005)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    done_before = sorted(p.name for p in split.iterdir() if not p.name.startswith("."))
    assert len(done_before) < 8, "the run finished before it could be killed"
    with pytest.raises(DatasetError, match="--resume"):
        generate(cfg, out, progress=False)
    rep = generate(cfg, out, resume=True, progress=False)
    assert rep.scenes_skipped == len(done_before)
    assert _digest(out) == _digest(ref)
    assert not list(split.glob(".*"))  # no partial scene folders left


def test_resume_refuses_other_config(tmp_path, tiny_config):
    generate(tiny_config.replace(scenes=1), tmp_path / "d", progress=False)
    with pytest.raises(DatasetError, match="frames_per_scene"):
        generate(tiny_config.replace(scenes=1, frames_per_scene=3), tmp_path / "d", resume=True, progress=False)
    rep = generate(tiny_config.replace(scenes=1), tmp_path / "d", overwrite=True, progress=False)
    assert rep.scenes_done == 1


def test_settled_objects_rest_without_interpenetration(tiny_config):
    import simtest.objects as objs

    objects = objs.load_object_set(tiny_config.objects)
    cfg = tiny_config.replace(**{"scene.objects_per_scene": [6, 8]})
    for scene_id in range(2):
        scene, result, _, _ = prepare_scene(cfg, objects, scene_id)
        assert result.at_rest, result
        m, d = scene.model, scene.data
        for i, active in enumerate(scene.active):
            if active:
                b, v = scene.instance_bodies[i], scene.instance_dofs[i]
                assert body_speed(m, d, b, v, body_radius(m, b)) < cfg.scene.settle_velocity
                R, t = scene.object_pose_world(i)
                assert t[2] > cfg.scene.table_height - 0.005
        mujoco.mj_forward(m, d)
        for c in d.contact[:d.ncon]:
            assert c.dist > -0.003, f"penetration {c.dist * 1000:.1f} mm between geoms {c.geom1} and {c.geom2}"


def test_bad_config_values_name_the_field(tmp_path):
    with pytest.raises(ConfigError, match=r"camera\.width = 3 is invalid; allowed: \[16, 8192\]"):
        GenerateConfig().replace(**{"camera.width": 3})
    with pytest.raises(ConfigError, match="rig = 'orbit'"):
        GenerateConfig.from_dict({"rig": "orbit"})
    with pytest.raises(ConfigError, match="unknown field"):
        GenerateConfig.from_dict({"scene": {"tabel_height": 1}})
    bad = tmp_path / "bad.toml"
    bad.write_text("scenes = -1\n")
    from simtest.generators.config import load_config

    with pytest.raises(ConfigError, match=str(bad)):
        load_config(bad)


def test_cli_generate_refuses_non_empty_folder(tmp_path, capsys):
    from simtest.cli import main

    (tmp_path / "x").mkdir()
    (tmp_path / "x" / "keep.txt").write_text("user data")
    code = main(["generate", "--objects", "builtin-small", "--scenes", "1", "--frames-per-scene", "1",
                 "--width", "64", "--out", str(tmp_path / "x"), "--quiet"])
    assert code == 2
    assert "not empty" in capsys.readouterr().err
    assert (tmp_path / "x" / "keep.txt").read_text() == "user data"
