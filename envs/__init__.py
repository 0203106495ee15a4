"""Closed-loop grasping: the ``simtest/PandaGrasp-v0`` gymnasium environment, a grasp planner and the scripted
episode runner that scores a pose estimator by whether the Panda can grasp with its estimate.

``import simtest.envs`` registers the environment::

    import gymnasium, simtest.envs
    env = gymnasium.make("simtest/PandaGrasp-v0", width=160, height=120)
    obs, info = env.reset(seed=0, options={"target": "can_0", "n_distractors": 0})

The main pieces import from here too (loaded on first use: MuJoCo and the robot are not imported by
``import simtest.envs``): ``from simtest.envs import PandaGraspEnv, GraspTask, run_episode, write_video``.
The env is a thin adapter over a :class:`~simtest.envs.task.GraspTask` (scene, physics, ground truth), which
planners and episodes also take directly.
"""

from __future__ import annotations

import gymnasium

ENV_ID = "simtest/PandaGrasp-v0"

if ENV_ID not in gymnasium.registry:
    gymnasium.register(id=ENV_ID, entry_point="simtest.envs.grasp_env:PandaGraspEnv", max_episode_steps=400)

#: Public names loaded from their modules on first use.
_LAZY = {"PandaGraspEnv": "simtest.envs.grasp_env", "GraspTask": "simtest.envs.task",
         "ObservationModel": "simtest.envs.observation", "run_episode": "simtest.envs.episode",
         "write_video": "simtest.io.video"}

__all__ = ["ENV_ID", *_LAZY]


def __getattr__(name: str):
    """The names of ``_LAZY``, imported from their modules when first asked."""
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
