"""``simtest bench pbr-quality``: settings parsed with named errors; a tiny real run scores each setting against a
cached reference of the same views (the reference against itself is exact)."""

from __future__ import annotations

import json
import subprocess
import sys

import numpy as np
import pytest

from simtest.errors import ConfigError

pytest.importorskip("mitsuba")
pytest.importorskip("pyoidn")


def test_settings_parse_and_bad_keys_and_values_are_named():
    from simtest.benchmarks.pbr_quality import BEFORE, DEFAULT, parse_setting, previous_auto_spp

    assert parse_setting("before") == BEFORE and parse_setting("default") == DEFAULT
    s = parse_setting("hq:spp=16,sampler=independent,guide_spp=1,denoise_quality=high,freeze=0")
    assert (s.name, s.spp, s.sampler, s.guide_spp, s.denoise_quality, s.freeze) == \
        ("hq", 16, "independent", 1, "high", False)
    assert BEFORE.samples(640, 480) == previous_auto_spp(640, 480) == 8 and BEFORE.samples(320, 240) == 16
    for bad, word in (("x:foo=1", "'foo'"), ("x:spp=0", "spp='0'"), ("x:sampler=sobol", "sobol"),
                      ("x:denoise_quality=ultra", "ultra"), ("x:freeze=yes", "freeze='yes'"), (":spp=4", "no name")):
        with pytest.raises(ConfigError, match=word):
            parse_setting(bad)


def test_renderer_refuses_unknown_sampler_and_denoiser_by_name():
    from simtest.camera import CameraModel
    from simtest.errors import RenderError
    from simtest.render.pbr import PbrRenderer

    import simtest  # noqa: F401
    import mujoco

    model = mujoco.MjModel.from_xml_string('<mujoco><worldbody><geom type="sphere" size="0.1"/>'
                                           '<camera name="c" pos="0 0 1"/></worldbody></mujoco>')
    cam = CameraModel(np.array([[40.0, 0, 15.5], [0, 40.0, 11.5], [0, 0, 1]]), 32, 24)
    with pytest.raises(RenderError, match="sobol"):
        PbrRenderer(model, cam, sampler="sobol")
    with pytest.raises(RenderError, match="ultra"):
        PbrRenderer(model, cam, denoise_quality="ultra")
    with pytest.raises(RenderError, match="guide"):
        PbrRenderer(model, cam, guide_spp=0)


def test_the_config_offers_exactly_the_renderers_samplers_and_denoiser_levels():
    import dataclasses

    from simtest.generators.config import RenderConfig
    from simtest.render.pbr import DENOISE_QUALITIES, SAMPLERS

    fields = {f.name: f for f in dataclasses.fields(RenderConfig)}
    assert tuple(fields["pbr_sampler"].metadata["choices"]) == SAMPLERS
    assert tuple(fields["pbr_denoise_quality"].metadata["choices"]) == DENOISE_QUALITIES
    assert RenderConfig().pbr_sampler == SAMPLERS[0] and RenderConfig().pbr_denoise_quality == "fast"


def test_a_tiny_run_scores_settings_against_a_cached_reference(tmp_path):
    out = tmp_path / "q.json"
    cmd = [sys.executable, "-m", "simtest", "bench", "pbr-quality", "--sizes", "32x24", "--scenes", "1",
           "--views", "2", "--reference-spp", "4", "--settings", "same:spp=4;low:spp=1,guide_spp=1",
           "--cache", str(tmp_path / "refs"), "--json", str(out)]
    res = subprocess.run(cmd, capture_output=True, text=True, timeout=600)
    assert res.returncode == 0, res.stderr[-2000:]
    assert "| same | 32x24 | 4 | multijitter | 4 | fast | yes |" in res.stdout
    rows = {r["setting"]["name"]: r for r in json.loads(out.read_text())["rows"]}
    # the reference is the default setting at 4 spp with seed 7, "same" renders other seeds: not equal, but close
    assert rows["same"]["psnr_mean"] > rows["low"]["psnr_mean"] > 10.0
    assert len(list((tmp_path / "refs").glob("ref_32x24_*_4spp.npy"))) == 2
    again = subprocess.run(cmd[:-2], capture_output=True, text=True, timeout=600)  # references from the cache
    assert again.returncode == 0 and "| same | 32x24 |" in again.stdout
