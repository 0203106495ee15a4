"""Fixtures for the grasping tests: one small-image env per module (real MuJoCo physics and rendering)."""

from __future__ import annotations

import pytest


@pytest.fixture(scope="module")
def env():
    """A 96x72 grasp env with no distractors by default (episodes set their own options)."""
    import simtest.envs  # noqa: F401  (registers the env)
    import gymnasium

    e = gymnasium.make("simtest/PandaGrasp-v0", width=96, height=72, render_mode="rgb_array", n_distractors=0)
    yield e
    e.close()
