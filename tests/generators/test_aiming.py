"""Weighted draws aim views, objects and occluders where a config weights them; without weights they draw what
the uniform sampler drew."""

from __future__ import annotations

import json

import numpy as np
import pytest

from simtest.errors import ConfigError
from simtest.generators.aiming import object_probabilities, weighted_part, weighted_uniform
from simtest.generators.config import GenerateConfig
from simtest.generators.pipeline import generate
from simtest.io.bop import pose_from_bop
from simtest.sweeps.adapt_targets import view_factors


def test_no_weights_draw_what_the_uniform_sampler_drew():
    a, b = np.random.default_rng(3), np.random.default_rng(3)
    assert [weighted_uniform(a, (0.45, 0.9), ()) for _ in range(5)] == [float(b.uniform(0.45, 0.9)) for _ in range(5)]
    assert weighted_part(a, (0.0, 1.0), ()) == (0.0, 1.0)


def test_weights_pick_parts_in_proportion():
    rng = np.random.default_rng(0)
    draws = np.array([weighted_uniform(rng, (0.0, 40.0), (0.0, 1.0, 0.0, 3.0)) for _ in range(2000)])
    assert ((draws >= 10) & (draws < 20) | (draws >= 30)).all()
    assert np.mean(draws >= 30) == pytest.approx(0.75, abs=0.04)
    assert object_probabilities([1, 7, 13], {"7": 2.0}).tolist() == [0.25, 0.5, 0.25]
    with pytest.raises(ConfigError, match=r"not in the object set; known ids: \[1, 7, 13\]"):
        object_probabilities([1, 7, 13], {"99": 1.0})


def test_unset_fields_are_not_recorded_and_bad_values_name_the_field():
    shell = GenerateConfig().to_dict()["shell"]
    assert "roll_range_deg" not in shell and "distance_weights" not in shell
    with pytest.raises(ConfigError, match="occlusion.visib_band .* and occlusion.level"):
        GenerateConfig.from_dict({"occlusion": {"visib_band": [0.2, 0.5], "level": "L1"}})
    with pytest.raises(ConfigError, match="shell.roll_weights"):
        GenerateConfig.from_dict({"shell": {"roll_weights": [0.0, 0.0]}})
    with pytest.raises(ConfigError, match="shell.roll_range_deg"):
        GenerateConfig.from_dict({"shell": {"roll_range_deg": [50, 40]}})


def test_roll_range_and_visibility_band_are_generated(tmp_path, small_config):
    cfg = small_config.replace(**{"shell.roll_range_deg": [150.0, 170.0], "occlusion.visib_band": [0.3, 0.7],
                                  "scenes": 1, "frames_per_scene": 3})
    generate(cfg, tmp_path / "aim", progress=False)
    scene = tmp_path / "aim" / "train_pbr" / "000000"
    cams = json.loads((scene / "scene_camera.json").read_text())
    gts = json.loads((scene / "scene_gt.json").read_text())
    info = json.loads((scene / "scene_gt_info.json").read_text())
    occ = json.loads((scene / "scene_occlusion.json").read_text())
    for im, cam in cams.items():
        T = pose_from_bop(cam["cam_R_w2c"], cam["cam_t_w2c"])
        gt = pose_from_bop(gts[im][0]["cam_R_m2c"], gts[im][0]["cam_t_m2c"])
        assert 150.0 - 1e-6 <= view_factors(T.R, T.t, gt.R, gt.t)[2] <= 170.0 + 1e-6
        rec = occ[im]
        assert rec["requested"] == "visib 0.3-0.7"
        if rec["target_gt_id"] is not None and rec["in_band"]:
            assert 0.3 <= info[im][rec["target_gt_id"]]["visib_fract"] <= 0.7
    assert sum(r["in_band"] for r in occ.values()) >= 2
