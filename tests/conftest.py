"""Shared fixtures: small real datasets (real MuJoCo physics and rendering, small images)."""

from __future__ import annotations

import os

import pytest

os.environ.setdefault("MUJOCO_GL", "egl")

import simtest  # noqa: E402,F401  (selects the GL backend before anything imports mujoco)


@pytest.fixture(scope="session")
def small_config():
    """A fast generation config: builtin-small objects, 160x120 images, 2 scenes x 3 frames."""
    from simtest.generators.config import GenerateConfig

    return GenerateConfig().replace(**{
        "objects": "builtin-small", "scenes": 2, "frames_per_scene": 3, "camera.width": 160,
        "camera.height": 120, "scene.objects_per_scene": [3, 5], "scene.distractors": [1, 2], "seed": 7})


@pytest.fixture(scope="session")
def small_dataset(tmp_path_factory, small_config):
    """A generated dataset folder (made once per test session)."""
    from simtest.generators.pipeline import generate

    out = tmp_path_factory.mktemp("ds") / "small"
    generate(small_config, out, progress=False)
    return out
