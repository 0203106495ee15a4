"""Command-line and output-folder safety: nothing is replaced without --overwrite, bad paths and values are one
line with exit code 2, files follow the umask, an interrupted generation resumes, one --opt parser, the shared
--quiet/-v switches, and a closed stdout pipe ends quietly."""

from __future__ import annotations

import argparse
import hashlib
import json
import logging
import os
import shutil
import stat
import subprocess
import sys
from pathlib import Path

import pytest

from simtest.cli import build_parser, main
from simtest.errors import ConfigError, DatasetError
from simtest.estimators.options import parse_options
from simtest.estimators.registry import load_estimator
from simtest.io.files import prepare_out_dir


def _one_error_line(capsys: pytest.CaptureFixture[str], *needles: str) -> str:
    """The captured stderr, which must be exactly one ``simtest CMD: error: ...`` line containing ``needles``."""
    err = capsys.readouterr().err
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    assert lines[0].startswith("simtest ") and ": error: " in lines[0], err
    assert "Traceback" not in err
    for n in needles:
        assert n in lines[0], (n, err)
    return lines[0]


def _digest(root: Path) -> dict[str, str]:
    return {str(p.relative_to(root)): hashlib.sha1(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file() and p.name != "manifest.json"}


@pytest.fixture(scope="module")
def tiny_toml(tmp_path_factory, small_config) -> Path:
    """A generation config file: 2 scenes x 1 frame of 64x48 pixels."""
    cfg = small_config.replace(**{"scenes": 2, "frames_per_scene": 1, "camera.width": 64, "camera.height": 48})
    path = tmp_path_factory.mktemp("cfg") / "tiny.toml"
    path.write_text(cfg.to_toml())
    return path


# --------------------------------------------------------------------------------------------------------
# The shared output-folder rule
def test_prepare_out_dir_rules(tmp_path):
    assert prepare_out_dir(tmp_path / "new") is False and not (tmp_path / "new").exists()  # nothing created
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "keep.txt").write_text("keep")
    with pytest.raises(DatasetError, match="busy.*is not empty; pass --overwrite"):
        prepare_out_dir(busy)
    with pytest.raises(DatasetError, match="--resume to continue it or --overwrite"):
        prepare_out_dir(busy, can_resume=True)
    assert prepare_out_dir(busy, resume=True, can_resume=True) is True
    assert prepare_out_dir(busy, overwrite=True) is True and (busy / "keep.txt").exists()  # written over, kept
    with pytest.raises(ConfigError, match="exclude each other"):
        prepare_out_dir(busy, overwrite=True, resume=True, can_resume=True)
    with pytest.raises(ConfigError, match="cannot resume"):
        prepare_out_dir(busy, resume=True)
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    with pytest.raises(DatasetError, match="a_file.*is a file"):
        prepare_out_dir(a_file, overwrite=True)
    with pytest.raises(DatasetError, match="cannot create.*a_file.*is a file"):
        prepare_out_dir(a_file / "sub" / "deeper")
    data = tmp_path / "data"
    data.mkdir()
    for inside in (data, data / "sub"):
        with pytest.raises(DatasetError, match="must not be, lie inside the input dataset"):
            prepare_out_dir(inside, overwrite=True, protect=[data])
    with pytest.raises(DatasetError, match="contain"):  # clearing the parent would delete the input
        prepare_out_dir(tmp_path, overwrite=True, clear=True, protect=[data])
    assert prepare_out_dir(busy, overwrite=True, clear=True) is False and not any(busy.iterdir())


# --------------------------------------------------------------------------------------------------------
# eval, grasp, sweep, demo, train, corrupt, generate: non-empty --out, the dataset itself, paths under files
def test_eval_never_replaces_results_without_overwrite(small_dataset, tmp_path, capsys):
    before = _digest(small_dataset)
    for out in (small_dataset, small_dataset / "train_pbr", small_dataset / "runs" / "x"):
        assert main(["eval", "--data", str(small_dataset), "--estimator", "oracle", "--out", str(out),
                     "--overwrite"]) == 2
        _one_error_line(capsys, "must not be", str(small_dataset))
    assert _digest(small_dataset) == before and not (small_dataset / "runs").exists()

    out = tmp_path / "run"
    out.mkdir()
    (out / "results.csv").write_text("mine\n")
    # refused before the estimator is loaded: a module that does not exist is never imported
    assert main(["eval", "--data", str(small_dataset), "--estimator", "no_such_module:Thing", "--out", str(out)]) == 2
    _one_error_line(capsys, str(out), "not empty", "--overwrite")
    assert main(["eval", "--results", str(out / "results.csv"), "--data", str(small_dataset), "--out", str(out)]) == 2
    _one_error_line(capsys, "not empty")
    assert (out / "results.csv").read_text() == "mine\n"

    old = os.umask(0o022)
    try:
        assert main(["eval", "--data", str(small_dataset), "--estimator", "oracle", "--max-images", "1", "--no-vsd",
                     "--quiet", "--out", str(out), "--overwrite"]) == 0
    finally:
        os.umask(old)
    assert (out / "results.csv").read_text().startswith("scene_id,im_id,obj_id")
    for name in ("results.csv", "metrics.json", "errors.csv", "failures.csv", "metrics.md"):
        assert stat.S_IMODE((out / name).stat().st_mode) == 0o644, name


def test_grasp_sweep_demo_train_refuse_a_non_empty_out(small_dataset, tmp_path, capsys):
    busy = tmp_path / "busy"
    busy.mkdir()
    (busy / "episodes.csv").write_text("mine\n")
    # grasp: checked before the estimator (a module that does not exist) or the robot is loaded
    assert main(["grasp", "--estimator", "no_such_module:Thing", "--out", str(busy)]) == 2
    _one_error_line(capsys, str(busy), "not empty", "--overwrite")
    sweep_cfg = tmp_path / "sweep.json"
    sweep_cfg.write_text(json.dumps({"estimators": [{"name": "oracle", "estimator": "oracle"}],
                                     "dataset": {"path": str(small_dataset)}, "grasp": {"episodes": 0}}))
    assert main(["sweep", str(sweep_cfg), "--out", str(busy)]) == 2
    _one_error_line(capsys, "not empty", "--resume", "--overwrite")
    assert main(["sweep", str(sweep_cfg), "--out", str(busy), "--resume"]) == 2
    _one_error_line(capsys, "no sweep_config.json")
    assert main(["sweep", str(sweep_cfg), "--out", str(small_dataset / "sweep"), "--overwrite"]) == 2
    _one_error_line(capsys, "must not be")
    assert main(["demo", "--out", str(busy)]) == 2
    _one_error_line(capsys, "not empty", "--resume", "--overwrite")
    assert main(["train", "keypoints", "--data", str(small_dataset), "--out", str(busy)]) == 2
    _one_error_line(capsys, "not empty", "--resume", "--overwrite")
    assert (busy / "episodes.csv").read_text() == "mine\n"


@pytest.mark.parametrize("where", ["file", "under_file"])
def test_out_path_errors_are_one_line(where, small_dataset, tiny_toml, tmp_path, capsys):
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    out = str(a_file if where == "file" else a_file / "sub")
    sweep_cfg = tmp_path / "sweep.json"
    sweep_cfg.write_text(json.dumps({"estimators": [{"name": "oracle", "estimator": "oracle"}],
                                     "dataset": {"path": str(small_dataset)}, "grasp": {"episodes": 0}}))
    commands = [
        ["generate", "--config", str(tiny_toml), "--out", out, "--quiet"],
        ["eval", "--data", str(small_dataset), "--estimator", "oracle", "--out", out],
        ["grasp", "--estimator", "oracle", "--episodes", "1", "--out", out],
        ["sweep", str(sweep_cfg), "--out", out],
        ["corrupt", "--in", str(small_dataset), "--out", out, "--weather", "fog"],
        ["train", "keypoints", "--data", str(small_dataset), "--out", out],
        ["demo", "--out", out],
        ["objects", "export", "--set", "builtin-small", "--out", out],
    ]
    for argv in commands:
        assert main(argv) == 2, argv
        _one_error_line(capsys, str(a_file), "is a file")
    assert a_file.read_text() == "x"


def test_os_error_backstop_is_one_line(tmp_path, capsys):
    """A path no command checks first (the preview PNG under a regular file) still gives one line, rc 2."""
    import cv2
    import numpy as np

    img = tmp_path / "img.png"
    cv2.imwrite(str(img), np.full((24, 32, 3), 128, np.uint8))
    a_file = tmp_path / "a_file"
    a_file.write_text("x")
    assert main(["corrupt", "--preview", str(img), "--corruptions", "fog", "--out", str(a_file / "grid.png")]) == 2
    _one_error_line(capsys, "simtest corrupt: error:", "a_file")
    assert main(["corrupt", "--preview", str(img), "--corruptions", "fog", "--out", str(tmp_path)]) == 2
    _one_error_line(capsys, "is a folder")


# --------------------------------------------------------------------------------------------------------
# File modes follow the umask
def test_generated_files_follow_the_umask(tiny_toml, tmp_path):
    out = tmp_path / "ds"
    old = os.umask(0o022)
    try:
        assert main(["generate", "--config", str(tiny_toml), "--out", str(out), "--quiet"]) == 0
    finally:
        os.umask(old)
    files = [p for p in out.rglob("*") if p.is_file()]
    dirs = [out] + [p for p in out.rglob("*") if p.is_dir()]
    assert len(files) > 10
    assert {oct(stat.S_IMODE(p.stat().st_mode)) for p in files} == {"0o644"}
    assert {oct(stat.S_IMODE(p.stat().st_mode)) for p in dirs} == {"0o755"}


# --------------------------------------------------------------------------------------------------------
# An interrupted generation (no manifest.json yet) resumes
def test_generation_without_manifest_resumes(tiny_toml, tmp_path, capsys):
    ref = tmp_path / "ref"
    assert main(["generate", "--config", str(tiny_toml), "--out", str(ref), "--quiet"]) == 0
    half = tmp_path / "half"
    shutil.copytree(ref, half)
    (half / "manifest.json").unlink()
    split = half / "train_pbr"
    (split / "000001").rename(split / ".000001.partial")  # killed while writing scene 1
    capsys.readouterr()
    assert main(["generate", "--config", str(tiny_toml), "--out", str(half), "--quiet"]) == 2
    _one_error_line(capsys, "interrupted generation", "1 complete and 1 partial", "--resume", "--overwrite")
    assert main(["generate", "--config", str(tiny_toml), "--out", str(half), "--quiet", "--resume"]) == 0
    assert "1 made, 1 already complete" in capsys.readouterr().out
    assert (half / "manifest.json").is_file() and not (split / ".000001.partial").exists()
    assert _digest(half) == _digest(ref)

    foreign = tmp_path / "foreign"
    foreign.mkdir()
    (foreign / "notes.txt").write_text("mine")
    assert main(["generate", "--config", str(tiny_toml), "--out", str(foreign), "--resume"]) == 2
    _one_error_line(capsys, "no manifest.json", "notes.txt")


# --------------------------------------------------------------------------------------------------------
# One --opt parser; option errors list the estimator's options
def test_parse_options_types():
    opts = parse_options(["a=3", "b=0.5", "c=TRUE", "d=none", "e-f=[1, 2]", "g=hello world", "h='7'", "i=1e-3"])
    assert opts == {"a": 3, "b": 0.5, "c": True, "d": None, "e_f": [1, 2], "g": "hello world", "h": "7",
                    "i": 0.001}
    assert type(opts["a"]) is int
    with pytest.raises(ConfigError, match="KEY=VALUE"):
        parse_options(["novalue"])
    with pytest.raises(ConfigError, match="does not parse"):
        parse_options(["x=[1, 2"])


def test_bad_options_list_the_valid_ones(small_dataset, tmp_path, capsys):
    with pytest.raises(ConfigError, match=r"unknown option\(s\) rot_noise.*valid options: rot_noise_deg=0\.0, "
                                          r"trans_noise_mm=0\.0, seed=0"):
        load_estimator("oracle", rot_noise=3)
    with pytest.raises(ConfigError, match=r"rot_noise_deg = 'abc' has the wrong type; expected float"):
        load_estimator("oracle", rot_noise_deg="abc")
    with pytest.raises(ConfigError, match=r"seed = 1\.5 .*expected int"):
        load_estimator("oracle", seed=1.5)
    assert main(["eval", "--data", str(small_dataset), "--estimator", "oracle", "--opt", "bogus=1",
                 "--out", str(tmp_path / "e")]) == 2
    _one_error_line(capsys, "unknown option(s) bogus", "rot_noise_deg=0.0")
    assert main(["grasp", "--estimator", "oracle", "--opt", "rot_noise_deg=abc", "--out", str(tmp_path / "g")]) == 2
    _one_error_line(capsys, "wrong type", "rot_noise_deg=0.0")
    assert not (tmp_path / "g").exists()


# --------------------------------------------------------------------------------------------------------
# Depth presets, config files, --quiet / -v on every command, a closed pipe
def test_grasp_depth_noise_shows_and_checks_the_real_presets(capsys):
    from simtest.corrupt import DEPTH_PRESETS

    with pytest.raises(SystemExit):
        main(["grasp", "--help"])
    text = capsys.readouterr().out
    assert "d435}" not in text and "e.g. d435" not in text
    assert all(name in text for name in DEPTH_PRESETS)
    with pytest.raises(SystemExit) as exc:
        main(["grasp", "--estimator", "oracle", "--out", "x", "--depth-noise", "d435"])
    assert exc.value.code == 2
    assert "realsense-d435" in capsys.readouterr().err


@pytest.mark.parametrize("content, needles", [
    (b'seed = 1\nobjects = "caf\xe9"\n', ["is not UTF-8", "0xe9", "line 2"]),
    (b"seed = 1\nscenes = = 3\n", ["does not parse", "line 2"]),
])
def test_bad_config_files_are_one_line(content, needles, tmp_path, capsys):
    path = tmp_path / "bad.toml"
    path.write_bytes(content)
    assert main(["generate", "--config", str(path), "--out", str(tmp_path / "o")]) == 2
    _one_error_line(capsys, str(path), *needles)
    assert main(["sweep", str(path), "--out", str(tmp_path / "o")]) == 2
    _one_error_line(capsys, str(path), *needles)


def _leaf_parsers(parser: argparse.ArgumentParser, name: str = "") -> dict[str, argparse.ArgumentParser]:
    subs = [a for a in parser._actions if isinstance(a, argparse._SubParsersAction)]
    if not subs:
        return {name: parser}
    out = {}
    for action in subs:
        for child_name, child in action.choices.items():
            out.update(_leaf_parsers(child, f"{name} {child_name}".strip()))
    return out


def test_every_command_has_quiet_and_verbose():
    leaves = _leaf_parsers(build_parser())
    assert {"generate", "corrupt", "eval", "grasp", "train", "sweep", "demo", "objects list",
            "bench generate"} <= set(leaves)
    for name, p in leaves.items():
        by_flag = {s: a for a in p._actions for s in a.option_strings}
        assert by_flag["--quiet"].dest == "quiet" and by_flag["--quiet"].default is False, name
        assert by_flag["-v"] is by_flag["--verbose"] and isinstance(by_flag["-v"], argparse._CountAction), name
    for name in ("eval", "corrupt", "train"):  # the old switch still works, hidden from --help
        p = leaves[name]
        assert any("--no-progress" in a.option_strings for a in p._actions)
        assert "--no-progress" not in p.format_help()


def test_no_progress_alias_means_quiet(small_dataset, tmp_path, capsys):
    assert main(["eval", "--data", str(small_dataset), "--estimator", "oracle", "--max-images", "1", "--no-vsd",
                 "--no-progress", "--out", str(tmp_path / "e")]) == 0
    err = capsys.readouterr().err
    assert "eval: " not in err.replace("simtest eval: --no-progress", "")  # no progress bar
    assert "--no-progress is deprecated; use --quiet" in err


def test_verbose_sets_the_simtest_log_level(capsys):
    for flags, level in (([], logging.WARNING), (["-v"], logging.INFO), (["-vv"], logging.DEBUG)):
        assert main(["objects", "list", "--set", "builtin-small", "--no-grasps", *flags]) == 0
        assert logging.getLogger("simtest").level == level
    logging.getLogger("simtest").setLevel(logging.NOTSET)


def test_closed_stdout_pipe_ends_quietly():
    proc = subprocess.Popen([sys.executable, "-m", "simtest", "objects", "list", "--set", "builtin-small",
                             "--no-grasps"], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    proc.stdout.close()  # the reader is gone before the first line is written (like `| head -0`)
    err = proc.stderr.read().decode()
    proc.wait()
    proc.stderr.close()
    assert "Traceback" not in err and "BrokenPipe" not in err and err.strip() == ""
    assert proc.returncode == 1


def test_two_writers_of_one_scene_never_share_a_partial_folder(tmp_path):
    """A resumed run and a straggling worker of the killed one may make the same scene at once: each assembles
    it in its own hidden folder, and whichever finishes second leaves the first one's complete folder."""
    import numpy as np

    from simtest.camera import CameraModel, default_intrinsics
    from simtest.io.bop import SceneWriter, scene_dirs

    split = tmp_path / "train_pbr"
    a, b = SceneWriter(split, 3), SceneWriter(split, 3)
    assert a.dir != b.dir and a.dir.name.startswith(".000003.") and a.dir.name.endswith(".partial")
    w, h = 64, 48
    cam = CameraModel(default_intrinsics(w, h), w, h)
    for writer in (a, b):
        writer.add(0, np.zeros((h, w, 3), np.uint8), np.ones((h, w), np.float32), cam, [], [], [])
    assert a.close() == b.close() == split / "000003"
    assert [d.name for d in scene_dirs(split)] == ["000003"]
    assert sorted(p.name for p in split.iterdir()) == ["000003"]  # no partial folder left behind
    assert (split / "000003" / "rgb" / "000000.jpg").exists()
