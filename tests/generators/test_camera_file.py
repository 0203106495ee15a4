"""``camera.file`` / ``simtest generate --camera``: a BOP ``camera.json`` gives the dataset's intrinsics, image size
and depth unit; a field given next to it must agree; a bad file is one error naming the file and the field.
(Rendering with such a camera, fast and pbr: tests/generators/test_pbr.py.)"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest

from simtest.camera import intrinsics_matrix
from simtest.errors import ConfigError
from simtest.generators.config import GenerateConfig, camera_file_values, load_config

#: LM-O's camera (BOP lmo/camera.json).
LMO = {"cx": 325.2611, "cy": 242.04899, "depth_scale": 1.0, "fx": 572.4114, "fy": 573.57043, "height": 480,
       "width": 640}


def _write(path: Path, data) -> Path:
    path.write_text(data if isinstance(data, str) else json.dumps(data))
    return path


def test_camera_file_sets_intrinsics_size_and_depth_scale(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    _write(tmp_path / "camera.json", {**LMO, "extra": "ignored"})
    cfg = GenerateConfig.from_dict({"camera": {"file": "camera.json"}})  # relative: to the working folder
    assert cfg.camera.file == str(tmp_path / "camera.json")
    assert (cfg.camera.width, cfg.camera.height) == (640, 480)
    np.testing.assert_array_equal(cfg.camera.K(), intrinsics_matrix(572.4114, 573.57043, 325.2611, 242.04899))
    assert cfg.render.depth_scale == 1.0
    assert camera_file_values(tmp_path / "camera.json") == {k: v for k, v in LMO.items()}
    # without depth_scale the config's own (default or given) stays
    no_scale = _write(tmp_path / "no_scale.json", {k: v for k, v in LMO.items() if k != "depth_scale"})
    assert GenerateConfig.from_dict({"camera": {"file": str(no_scale)}}).render.depth_scale == 0.1
    assert GenerateConfig.from_dict({"camera": {"file": str(no_scale)},
                                     "render": {"depth_scale": 0.5}}).render.depth_scale == 0.5


def test_camera_file_round_trips_and_a_new_file_replaces_the_values(tmp_path):
    lmo = _write(tmp_path / "lmo.json", LMO)
    other = _write(tmp_path / "other.json", {"fx": 300.0, "fy": 310.0, "cx": 159.5, "cy": 119.5, "width": 320,
                                             "height": 240, "depth_scale": 0.25})
    cfg = GenerateConfig().replace(**{"camera.file": str(lmo), "scenes": 3})
    path = tmp_path / "c.toml"
    path.write_text(cfg.to_toml())  # the file and its values, which agree with it
    assert 'file = "' in path.read_text() and load_config(path) == cfg
    assert cfg.replace(seed=4).camera == cfg.camera
    # a new file takes all its values, over values the config gives (also explicit ones, as a config file's)
    explicit = GenerateConfig().replace(**{"camera.fx": 600.0, "camera.width": 800, "render.depth_scale": 0.1})
    for base in (cfg, explicit):
        new = base.replace(**{"camera.file": str(other)})
        assert (new.camera.fx, new.camera.fy, new.camera.width, new.render.depth_scale) == (300.0, 310.0, 320, 0.25)
    dropped = cfg.replace(**{"camera.file": None})  # the values stay, no longer tied to the file
    assert dropped.camera.file is None and dropped.camera.fx == LMO["fx"]
    assert dropped.replace(**{"camera.fx": 500.0}).camera.fx == 500.0


def test_fields_given_with_the_file_must_agree_with_it(tmp_path):
    lmo = str(_write(tmp_path / "camera.json", LMO))
    same = GenerateConfig.from_dict({"camera": {"file": lmo, "width": 640, "fx": 572.4114},
                                     "render": {"depth_scale": 1}})
    assert same.camera.fx == 572.4114
    with pytest.raises(ConfigError, match=r"config: camera\.width = 320 conflicts with camera\.file '.*camera\.json', "
                                          r"whose width is 640"):
        GenerateConfig.from_dict({"camera": {"file": lmo, "width": 320}})
    with pytest.raises(ConfigError, match=r"render\.depth_scale = 0\.1 conflicts with camera\.file .* depth_scale is "
                                          r"1\.0"):
        GenerateConfig.from_dict({"camera": {"file": lmo}, "render": {"depth_scale": 0.1}})
    with pytest.raises(ConfigError, match=r"overrides: camera\.fy = 500\.0 conflicts"):
        GenerateConfig().replace(**{"camera.file": lmo}).replace(**{"camera.fy": 500.0})


@pytest.mark.parametrize("content, message", [
    ({k: v for k, v in LMO.items() if k != "fy"}, r"field 'fy' is missing"),
    ({**LMO, "fx": "572.4"}, r"field 'fx' is '572\.4'; allowed: a finite number > 0"),
    ({**LMO, "fx": 0}, r"field 'fx' is 0; allowed: a finite number > 0"),
    ({**LMO, "cy": None}, r"field 'cy' is None; allowed: a finite number"),
    ({**LMO, "width": 640.5}, r"field 'width' is 640\.5; allowed: a positive integer"),
    ({**LMO, "depth_scale": -1.0}, r"field 'depth_scale' is -1\.0; allowed: a finite number > 0"),
    ({**LMO, "height": 8}, r"height = 8 is invalid; allowed: \[16, 8192\]"),
    ({**LMO, "cx": 3252.611}, r"field 'cx' is 3252\.611; allowed: a principal point inside the image, "
                              r"\[-0\.5, 639\.5\] for width 640"),
    ([572.4114, 573.57043], r"expected a JSON object"),
    ('{"fx": 572.4,', r"not valid JSON at line 1"),
])
def test_bad_camera_files_name_the_file_and_field(tmp_path, content, message):
    path = _write(tmp_path / "camera.json", content)
    with pytest.raises(ConfigError, match=rf"^cam\.toml: camera\.file: {re.escape(str(path))}: .*{message}"):
        GenerateConfig.from_dict({"camera": {"file": str(path)}}, source="cam.toml")


def test_a_missing_or_malformed_path_is_named(tmp_path):
    with pytest.raises(ConfigError, match=rf"camera\.file: {re.escape(str(tmp_path / 'nope.json'))}: file is missing"):
        GenerateConfig.from_dict({"camera": {"file": str(tmp_path / "nope.json")}})
    for bad in (5, "", True):
        with pytest.raises(ConfigError, match=r"camera\.file = .* is invalid; allowed: the path of a BOP camera\.json"):
            GenerateConfig.from_dict({"camera": {"file": bad}})


def test_workers_get_the_values_not_the_file(tmp_path):
    cfg = GenerateConfig().replace(**{"camera.file": str(_write(tmp_path / "camera.json", LMO))})
    (tmp_path / "camera.json").unlink()  # a worker where the path does not exist
    rebuilt = GenerateConfig.from_dict(cfg.to_dict(camera_file=False))  # what generate's workers rebuild
    assert rebuilt.camera.file is None
    np.testing.assert_array_equal(rebuilt.camera.K(), cfg.camera.K())
    assert (rebuilt.camera.width, rebuilt.camera.height, rebuilt.render.depth_scale) == (640, 480, 1.0)


def test_cli_camera_option(tmp_path, capsys):
    from simtest.cli import main

    lmo = _write(tmp_path / "camera.json", LMO)
    assert main(["generate", "--camera", str(lmo), "--print-config"]) == 0
    text = capsys.readouterr().out
    assert f'file = "{lmo}"' in text and "fx = 572.4114" in text and "depth_scale = 1.0" in text
    # --camera replaces the config file's camera values (the command line over the config file)
    toml = tmp_path / "c.toml"
    toml.write_text("[camera]\nwidth = 320\nheight = 240\nfx = 300.0\n[render]\ndepth_scale = 0.1\n")
    assert main(["generate", "--config", str(toml), "--camera", str(lmo), "--print-config"]) == 0
    text = capsys.readouterr().out
    assert "width = 640" in text and "fx = 572.4114" in text and "depth_scale = 1.0" in text
    # ... but a value given with it on the command line must agree
    out = tmp_path / "ds"
    assert main(["generate", "--camera", str(lmo), "--width", "320", "--out", str(out), "--quiet"]) == 2
    assert "command line: camera.width = 320 conflicts with camera.file" in capsys.readouterr().err
    assert main(["generate", "--camera", str(lmo), "--width", "640", "--print-config"]) == 0
    capsys.readouterr()
    bad = _write(tmp_path / "bad.json", {**LMO, "fx": "wide"})
    assert main(["generate", "--camera", str(bad), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert f"camera.file: {bad}: field 'fx' is 'wide'" in err and len(err.strip().splitlines()) == 1
    assert not out.exists()
