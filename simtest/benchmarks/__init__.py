"""Speed benchmarks (``simtest bench generate|grasp|metrics|corruptions|panda|objects|backend|channels|stereo|appearance``), reported as ratios against raw
MuJoCo (or as milliseconds per call) measured in the same run; never timed assertions in tests.

* :mod:`.generate` — dataset generation frames/s vs raw ``mujoco.Renderer`` rendering; 1 vs 2 workers.
* :mod:`.grasp` — grasp env steps/s vs raw ``mj_step``; wall time per oracle episode.
* :mod:`.metrics` — milliseconds per call of each pose metric on a fixed synthetic model.
* :mod:`.corruptions` — milliseconds per call of each ImageNet-C corruption at 640 x 480.
* :mod:`.panda` — Panda model ``mj_step``/s at rest and moving; one scripted grasp (no rendering).
* :mod:`.objects` — load time and first-scene time of a small vs a large generated mesh library.
* :mod:`.backend`, :mod:`.channels`, :mod:`.stereo` — local vs Ray workers; dense channels; the stereo sensor.
* :mod:`.appearance` — rg-chromaticity spread inside objects' visible masks (about 0.02 flat-coloured, 0.04-0.2
  printed or textured); not a speed figure, a measure of how much the objects' surfaces vary.

These are orchestration modules: they drive :mod:`simtest.generators` and :mod:`simtest.envs`, imported lazily.
"""
