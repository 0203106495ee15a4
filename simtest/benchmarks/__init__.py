"""Speed benchmarks (``simtest bench generate|grasp|metrics|corruptions|panda|objects``), reported as ratios against raw
MuJoCo (or as milliseconds per call) measured in the same run; never timed assertions in tests.

* :mod:`.generate` — dataset generation frames/s vs raw ``mujoco.Renderer`` rendering; 1 vs 2 workers.
* :mod:`.grasp` — grasp env steps/s vs raw ``mj_step``; wall time per oracle episode.
* :mod:`.metrics` — milliseconds per call of each pose metric on a fixed synthetic model.
* :mod:`.corruptions` — milliseconds per call of each ImageNet-C corruption at 640 x 480.
* :mod:`.panda` — Panda model ``mj_step``/s at rest and moving; one scripted grasp (no rendering).
* :mod:`.objects` — load time and first-scene time of a small vs a large generated mesh library.

These are orchestration modules: they drive :mod:`simtest.generators` and :mod:`simtest.envs`, imported lazily.
"""
