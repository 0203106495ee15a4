"""Closed-loop grasping: the ``simtest/PandaGrasp-v0`` gymnasium environment, a grasp planner and the scripted
episode runner that scores a pose estimator by whether the Panda can grasp with its estimate.

``import simtest.envs`` registers the environment::

    import gymnasium, simtest.envs
    env = gymnasium.make("simtest/PandaGrasp-v0", width=160, height=120)
    obs, info = env.reset(seed=0, options={"target": "can_0", "n_distractors": 0})
"""

from __future__ import annotations

import gymnasium

ENV_ID = "simtest/PandaGrasp-v0"

if ENV_ID not in gymnasium.registry:
    gymnasium.register(id=ENV_ID, entry_point="simtest.envs.grasp_env:PandaGraspEnv", max_episode_steps=400)

__all__ = ["ENV_ID"]
