"""The Python front door: one function per job, plain arguments with the command line's defaults, result objects
back. ``import simtest`` then ``simtest.generate(...)``, ``simtest.evaluate(...)``, ``simtest.grasp(...)``,
``simtest.sweep(...)``, ``simtest.load_objects(...)``; each is a thin layer over the module that does the work
(named in its docstring), so everything the CLI can set is reachable from there too.

Example (a tiny dataset, then the oracle scored on it)::

    import simtest
    ds = simtest.generate("out/small", objects="builtin-small", scenes=1, frames_per_scene=2, width=160,
                          height=120)
    report = simtest.evaluate("out/small", "oracle", out="out/small-eval")
    print(report.overall["add_s_or_add_01d"], report.overall["ci95"]["add_s_or_add_01d"])
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

__all__ = ["generate", "evaluate", "grasp", "sweep", "load_objects"]


def load_objects(spec: str | Path = "builtin", *, units: str = "auto", scale: float = 1.0, seed: int = 0,
                 symmetry: str = "auto"):
    """An object set: ``"builtin"``, ``"builtin-small"``, a BOP ``models/`` folder, a mesh folder or one mesh
    file (:func:`simtest.objects.load_object_set`; ``units`` of the files: m, cm, mm or auto)."""
    from simtest.objects import load_object_set

    return load_object_set(spec, units=units, seed=seed, scale=scale, symmetry=symmetry)


def generate(out: str | Path, *, objects: str | Path | None = None, scenes: int | None = None,
             frames_per_scene: int | None = None, width: int | None = None, height: int | None = None,
             camera: str | Path | None = None, profile: str | None = None, recipe: str | None = None,
             config: str | Path | None = None, seed: int | None = None, workers: int | None = None,
             options: dict[str, Any] | None = None, resume: bool = False, overwrite: bool = False,
             progress: bool = True):
    """Generate a BOP dataset in ``out`` (``simtest generate``; :func:`simtest.generators.pipeline.generate`).

    Args:
        out: Dataset folder (empty or absent unless ``resume`` / ``overwrite``).
        objects: Object set (see :func:`load_objects`); None: the config's (``builtin``).
        scenes, frames_per_scene: How many (None: the config's).
        width, height: Image size in pixels (a width alone gets a 4:3 height).
        camera: A BOP ``camera.json`` whose intrinsics and size to use.
        profile: Render profile: ``fast``, ``quality`` or ``pbr``.
        recipe: ``tabletop`` or ``bop-pbr``.
        config: A TOML config file to start from (``simtest generate --config``).
        seed, workers: Master seed; worker processes.
        options: More config values by dotted key, e.g. ``{"scene.distractors": [2, 4]}`` (``simtest generate
            --print-config`` lists them).
        resume, overwrite, progress: As on the command line.

    Returns:
        The :class:`~simtest.generators.pipeline.GenerateReport` (frames written, frames per second, ...).
    """
    from simtest.generators.config import GenerateConfig, load_config
    from simtest.generators.pipeline import generate as run

    cfg = load_config(config) if config is not None else GenerateConfig()
    values = {"objects": None if objects is None else str(objects), "scenes": scenes,
              "frames_per_scene": frames_per_scene, "camera.width": width, "camera.height": height,
              "camera.file": None if camera is None else str(camera), "render.profile": profile, "recipe": recipe,
              "seed": seed, "workers": workers, **(options or {})}
    if width is not None and height is None and camera is None and config is None:
        values["camera.height"] = int(width) * 3 // 4
    values = {k: v for k, v in values.items() if v is not None}
    return run(cfg.replace(**values) if values else cfg, out, resume=resume, overwrite=overwrite, progress=progress,
               command_line=["simtest.generate"])


def evaluate(data: str | Path, estimator: Any = "oracle", *, out: str | Path | None = None,
             options: dict[str, Any] | None = None, split: str | None = None, task: str = "localization",
             max_images: int | None = None, vsd: bool = True, workers: int = 1, overwrite: bool = False,
             progress: bool = True):
    """Run a pose estimator on a BOP dataset and score it (``simtest eval``;
    :func:`simtest.evaluation.run.evaluate`).

    Args:
        data: Dataset folder (a simtest dataset or a real BOP one as distributed).
        estimator: Registered name (``oracle``, ``icp``, ``segicp``, ``keypoints``, ...), ``module:attr``, or an
            estimator object.
        out: Run folder for results.csv, metrics.json, errors.csv, metrics.md (None: nothing written).
        options: The estimator's options (``--opt KEY=VALUE``).
        split, task, max_images, vsd, workers, overwrite, progress: As on the command line.

    Returns:
        The :class:`~simtest.evaluation.run.EvalReport`: ``overall``, ``per_object`` (each with ``ci95``, the
        95 % intervals of the proportions), ``table()``.
    """
    from simtest.backend import Backend
    from simtest.evaluation.run import evaluate as run

    return run(data, estimator, split=split, task=task, max_images=max_images, vsd=vsd, out_dir=out,
               estimator_options=options, overwrite=overwrite, progress=progress,
               backend=Backend("local", int(workers)) if int(workers) > 1 else None)


def grasp(estimator: str = "oracle", *, episodes: int = 10, objects: str = "builtin", out: str | Path | None = None,
          options: dict[str, Any] | None = None, seed: int = 0, overwrite: bool = False, progress: bool = True,
          **settings: Any):
    """Closed-loop grasping with the Panda's wrist camera, the estimate driving the grasp (``simtest grasp``;
    :func:`simtest.envs.runner.run_grasp_episodes`).

    Args:
        estimator: Registered name or ``module:attr``; ``options`` its options.
        episodes, objects, seed: How many episodes, of which object set, from which master seed.
        out: Run folder for episodes.csv and summary.json / summary.md (None: nothing written).
        settings: Any other field of :class:`~simtest.envs.runner.GraspRunConfig` (``occlusion="L2"``,
            ``width=320``, ``depth_sensor="d435-stereo"``, ``video=True`` ...).

    Returns:
        The :class:`~simtest.envs.runner.GraspRunReport` (success rate with its 95 % interval, per episode).
    """
    from simtest.envs.runner import GraspRunConfig, run_grasp_episodes

    cfg = GraspRunConfig(estimator=estimator, estimator_options=dict(options or {}), episodes=int(episodes),
                         objects=str(objects), seed=int(seed), **settings)
    return run_grasp_episodes(cfg, out, progress=progress, overwrite=overwrite)


def sweep(config: str | Path | dict[str, Any], out: str | Path, *, resume: bool = False, overwrite: bool = False,
          progress: bool = True):
    """A robustness sweep: estimators x conditions, scored, with the HTML report (``simtest sweep``;
    :func:`simtest.sweeps.grid.run_sweep`). ``config`` is a TOML / JSON file or the same content as a dict."""
    from simtest.sweeps.grid import SweepConfig, load_sweep_config, run_sweep

    cfg = SweepConfig.from_dict(config, source="simtest.sweep") if isinstance(config, dict) else \
        load_sweep_config(config)
    return run_sweep(cfg, out, resume=resume, overwrite=overwrite, progress=progress)
