"""Many closed-loop episodes: seeding, worker processes (each with its own grasp task), the run's outputs.

Episode ``i`` of a run with master seed ``s`` resets its env with the seed drawn from ``SeedSequence`` child
``i`` of ``s`` (:func:`episode_seed`), so every episode's scene, corruption and oracle noise are the same
whichever worker runs it, however many workers there are and whichever back end runs them (``local``
processes or ``ray`` tasks, :mod:`simtest.backend`). Workers own whole episodes, each with its own env,
renderer and estimator.

An episode whose Ray worker (or node) is lost more often than the retries allow is left out: the run writes
the episodes that finished, lists the lost ones in ``summary.json`` (``run.lost_episodes``) and then raises
:class:`~simtest.backend.BackendError`, since its success rate covers fewer episodes than asked for.
"""

from __future__ import annotations

import csv
import functools
import math
import importlib
import sys
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

from tqdm import tqdm

from simtest.backend import Backend, BackendError, RunStats, preflight, run_units
from simtest.camera import CameraModel
from simtest.envs import summary as run_summary
from simtest.envs.episode import run_episode
from simtest.envs.observation import ObservationModel, resolve_depth_sensor
from simtest.envs.observation_record import OBSERVATIONS_FOLDER, write_observation_models, write_observation_scene
from simtest.envs.options import CONTROL_DT, EpisodeConfig, load_objects
from simtest.envs.planner import OBSTACLE_SOURCES, GraspPlanner
from simtest.envs.reobserve import (FUSIONS, STAGE_COLUMNS, UPDATES, check_choice, parse_reobserve, stage_markdown,
                                    stage_table)
from simtest.envs.task import GraspTask
from simtest.errors import ConfigError, EstimatorError
from simtest.estimators.base import estimator_label
from simtest.estimators.guard import DEFAULT_TIMEOUT_S, check_timeout
from simtest.estimators.registry import load_estimator
from simtest.io.files import prepare_out_dir
from simtest.io import video as video_files
from simtest.backend.threads import worker_threads
from simtest.rng import child_sequence

__all__ = ["GraspRunConfig", "GraspRunReport", "episode_seed", "run_grasp_episodes", "ESTIMATOR_FAULTS",
           "check_planner_obstacles", "RECORD_EVERY"]

#: Names that moved out of this module; ``from simtest.envs.runner import NAME`` still works, with a
#: DeprecationWarning.
MOVED = {"wilson_interval": "simtest.metrics.intervals", "write_video": "simtest.io.video",
         "summarize": "simtest.envs.summary", "summary_markdown": "simtest.envs.summary",
         "CSV_COLUMNS": "simtest.envs.summary", "noise_sweep": "simtest.envs.noise_sweep",
         "NoiseSweepResult": "simtest.envs.noise_sweep"}


def __getattr__(name: str) -> Any:
    """The moved names (:data:`MOVED`), from their new module, with a DeprecationWarning."""
    if name in MOVED:
        warnings.warn(f"simtest.envs.runner.{name} moved to {MOVED[name]}.{name}", DeprecationWarning,
                      stacklevel=2)
        return getattr(importlib.import_module(MOVED[name]), name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

#: Episode outcomes that are faults of the estimator (``fail_fast`` stops at the first).
ESTIMATOR_FAULTS = ("estimator_error", "estimator_timeout")
#: Video frames are recorded every this many control periods.
RECORD_EVERY = 2


def episode_seed(seed: int, index: int) -> int:
    """The env seed of episode ``index`` under master ``seed``: SeedSequence child ``index``, as a uint32."""
    return int(child_sequence(seed, index).generate_state(1)[0])


@dataclass(frozen=True)
class GraspRunConfig:
    """What a grasp benchmark run does.

    Attributes:
        estimator: Registered name or ``module:attr``.
        estimator_options: Keyword options of the estimator.
        episodes: Number of episodes.
        seed: Master seed.
        objects: Object set.
        units, scale: Units and scale factor of its mesh files (see :func:`simtest.objects.load_object_set`).
        targets: Targets cycled over the episodes (obj_ids or names); empty: a random graspable object per
            episode; ``("all",)``: every graspable object of the set in turn.
        n_distractors: Distractor objects per scene.
        occlusion: ``"L0".."L3"``.
        weather, severity: Image corruption of the observation (None = clean).
        depth_noise: Depth-noise preset (None = clean).
        depth_sensor: ``"none"`` (exact depth) or a simulated stereo sensor (``"d435-stereo"``,
            ``"passive-stereo"``): the estimator and the planner see its sensed depth (see ``PandaGraspEnv``).
        width, height: Wrist camera size, pixels.
        workers: Worker processes (local), or the CPUs of a Ray instance started here.
        backend: Where the episodes run: ``"local"`` or ``"ray"`` (:mod:`simtest.backend`); not part of the
            results.
        ray_address: With ``backend="ray"``: ``"auto"`` or ``HOST:PORT`` of a running cluster; ``None`` starts a
            local Ray instance.
        video: Write a GIF per episode (third-person | wrist) for the first ``video_episodes`` episodes.
        video_episodes: How many episodes get a video.
        timeout: Time limit of the estimator call per episode, seconds (``None`` or 0: none); over it the
            episode ends as ``estimator_timeout`` and the run goes on.
        fail_fast: Stop at the first episode the estimator fails (``estimator_error`` / ``estimator_timeout``)
            by raising :class:`~simtest.errors.EstimatorError` with its traceback.
        planner_obstacles: Where the grasp planner's collision check takes the obstacles from
            (:data:`simtest.envs.planner.OBSTACLE_SOURCES`): ``"sim"`` (the simulator's geometry) or
            ``"observed"`` (only what the observation's depth image shows; the table stays known).
        reobserve: Looks on the way in: ``"none"``, ``"pregrasp"`` or ``"approach:K"``
            (:mod:`simtest.envs.reobserve`); with looks, ``stages.csv`` and a per-stage error table are written.
        reobserve_update, reobserve_fusion: How a look updates the pose (``"estimate"`` | ``"track"``) and how the
            looks are combined (``"mean"`` | ``"latest"``).
        task: ``"single"`` (one target per episode) or ``"declutter"`` (clutter removal rounds,
            :mod:`simtest.envs.declutter`; ``episodes`` counts rounds).
        scene: With ``task="declutter"``: ``"pile"`` or ``"packed"``.
        objects_per_scene: With ``task="declutter"``: objects on the table at the start of a round.
        looks: Dress every scene in the generator's looks (materials, prints, environment, lights), as datasets
            are drawn (default); False: the plain look of earlier releases. Poses and masks are the same either
            way (:mod:`simtest.envs.looks`).
        observation_profile: How the wrist camera's captures are rendered
            (:data:`simtest.envs.observation.OBSERVATION_PROFILES`): ``fast``, ``quality`` (shadows, MSAA) or
            ``pbr`` (path-traced RGB of the captures only; depth and masks from the rasterizer).
        save_observations: Write every episode's wrist captures as a BOP dataset in ``OUT/observations``
            (:mod:`simtest.envs.observation_record`), for ``simtest eval`` and ``simtest show``.
    """

    estimator: str = "oracle"
    estimator_options: dict = field(default_factory=dict)
    episodes: int = 10
    seed: int = 0
    objects: str = "builtin"
    units: str = "auto"
    scale: float = 1.0
    targets: tuple = ()
    n_distractors: int = 0
    occlusion: str = "L0"
    weather: str | None = None
    severity: int = 3
    depth_noise: str | None = None
    depth_sensor: str = "none"
    width: int = 320
    height: int = 240
    workers: int = 1
    backend: str = "local"
    ray_address: str | None = None
    video: bool = False
    video_episodes: int = 5
    timeout: float | None = DEFAULT_TIMEOUT_S
    fail_fast: bool = False
    planner_obstacles: str = "sim"
    reobserve: str = "none"
    reobserve_update: str = "estimate"
    reobserve_fusion: str = "mean"
    task: str = "single"
    scene: str = "pile"
    objects_per_scene: int = 5
    # How the wrist camera's scenes look, and what is kept of its captures.
    looks: bool = True
    observation_profile: str = "fast"
    save_observations: bool = False

    def reset_options(self, index: int, target_list: Sequence) -> dict:
        opts: dict[str, Any] = {"objects": self.objects, "n_distractors": self.n_distractors,
                                "occlusion": self.occlusion, "depth_noise": self.depth_noise,
                                "corruption": None if self.weather is None else
                                {"weather": self.weather, "severity": self.severity}}
        if target_list:
            opts["target"] = target_list[index % len(target_list)]
        return opts

    def to_dict(self) -> dict:
        """The fields as plain values; those of :data:`LATER_FIELDS` only when they differ from their
        defaults (so the records of plain runs stay as they were)."""
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()
                if k not in LATER_FIELDS or v != LATER_FIELDS[k]}


#: Fields written into records only when not at these defaults (see :meth:`GraspRunConfig.to_dict`).
LATER_FIELDS = {"reobserve": "none", "reobserve_update": "estimate", "reobserve_fusion": "mean", "task": "single",
                "scene": "pile", "objects_per_scene": 5}


@dataclass
class GraspRunReport:
    """Rows and summary of a run (see :func:`summarize` for the summary's keys)."""

    rows: list[dict]
    summary: dict
    out_dir: Path | None = None
    run: RunStats = field(default_factory=RunStats)  # what the back end did (episodes retried, lost)

    def table(self) -> str:
        """The summary as Markdown tables (:func:`simtest.envs.summary.summary_markdown`)."""
        return run_summary.summary_markdown(self.summary)

    def all_estimator_faults(self) -> bool:
        """Whether every episode ended in a fault of the estimator (a run that measured nothing)."""
        return bool(self.rows) and all(r["reason"] in ESTIMATOR_FAULTS for r in self.rows)

    def estimator_faults(self) -> int:
        """Episodes in which the estimator itself failed (raised, exited, timed out, returned garbage)."""
        return sum(r["reason"] in ESTIMATOR_FAULTS for r in self.rows)

    def failure_summary(self) -> str:
        """One line: how many episodes the estimator failed, by reason, and the first error."""
        bad = [r for r in self.rows if r["reason"] in ESTIMATOR_FAULTS]
        kinds = ", ".join(f"{k} {sum(r['reason'] == k for r in bad)}" for k in ESTIMATOR_FAULTS
                          if any(r["reason"] == k for r in bad))
        first = " ".join(str(bad[0]["error"]).split()) if bad else ""
        return f"the estimator failed in {len(bad)} of {len(self.rows)} episodes ({kinds}); first: {first}"


def _resolve_targets(cfg: GraspRunConfig) -> list:
    if not cfg.targets:
        return []
    if tuple(cfg.targets) == ("all",):
        return [o.obj_id for o in load_objects(cfg.objects, cfg.units, cfg.scale) if o.graspable]
    return list(cfg.targets)


# --- one episode (in this process or a worker) -----------------------------------------------------------
_WORKER: dict = {}


def _worker_init(cfg_dict: dict, out_dir: str | None) -> None:
    cfg = GraspRunConfig(**{**cfg_dict, "targets": tuple(cfg_dict["targets"])})
    worker_threads(cfg.workers, cfg.ray_address, apply=True)  # its share of the cores
    _WORKER.clear()
    _WORKER.update(_make_context(cfg, out_dir))


def _make_context(cfg: GraspRunConfig, out_dir: str | None) -> dict:
    task = GraspTask(width=cfg.width, height=cfg.height, episode={"objects": cfg.objects},
                     observation=ObservationModel(depth_sensor=cfg.depth_sensor, profile=cfg.observation_profile),
                     object_units=cfg.units,
                     object_scale=cfg.scale, render_width=max(cfg.width, 320), render_height=max(cfg.height, 240),
                     looks=cfg.looks)
    if cfg.save_observations and out_dir is not None:
        task.captures = []
    est = load_estimator(cfg.estimator, **cfg.estimator_options)
    return {"cfg": cfg, "task": task, "estimator": est, "targets": _resolve_targets(cfg), "out": out_dir,
            "planner": GraspPlanner(obstacles=cfg.planner_obstacles), "label": estimator_label(cfg.estimator, est)}


def _run_one(index: int, ctx: dict | None = None) -> dict:
    ctx = ctx if ctx is not None else _WORKER
    cfg: GraspRunConfig = ctx["cfg"]
    seed = episode_seed(cfg.seed, index)
    record = bool(cfg.video and ctx["out"] is not None and index < cfg.video_episodes)
    res = run_episode(ctx["task"], ctx["estimator"], ctx["planner"], seed=seed,
                      options=cfg.reset_options(index, ctx["targets"]), record=record, record_every=RECORD_EVERY,
                      timeout=cfg.timeout, reobserve=cfg.reobserve, reobserve_update=cfg.reobserve_update,
                      reobserve_fusion=cfg.reobserve_fusion)
    row = {"episode": index, **res.to_row(), "estimator_label": ctx["label"]}  # the label is not a CSV column
    row["error"] = run_summary.failure_words(row)
    if ctx["task"].captures is not None:
        task = ctx["task"]
        root = Path(ctx["out"]) / OBSERVATIONS_FOLDER
        write_observation_scene(task.captures, task.objects, root, index, task.depth_sensor != "none")
    if res.stages:
        row["stages"] = res.stages
    if record and res.frames:
        path = Path(ctx["out"]) / "videos" / f"episode_{index:04d}_{res.target_name}_{res.reason}.gif"
        video_files.write_video(res.frames, path, fps=1.0 / (CONTROL_DT * RECORD_EVERY))  # real time
    return row


def run_grasp_episodes(cfg: GraspRunConfig, out_dir: str | Path | None = None, *, progress: bool = True,
                       command_line: Sequence[str] | None = None, overwrite: bool = False) -> GraspRunReport:
    """Run ``cfg.episodes`` closed-loop episodes and (with ``out_dir``) write the outputs.

    Outputs (:mod:`simtest.envs.summary`): ``episodes.csv`` (one row per episode, ``CSV_COLUMNS``), ``summary.json`` and
    ``summary.md`` (success rate with a 95 % Wilson interval, per object, per failure reason, pose errors),
    and with ``cfg.video`` ``videos/episode_NNNN_<object>_<reason>.gif`` (or ``.mp4``).

    Estimator faults (exceptions, ``sys.exit``, timeouts, invalid return values) end their episode as
    ``estimator_error`` or ``estimator_timeout`` (message in the ``error`` column, the last frames of the
    traceback in ``traceback``) and the run goes on, unless ``cfg.fail_fast``.
    ``out_dir`` must be empty or absent unless ``overwrite`` (its files of these names are then replaced);
    this is checked before anything is loaded.

    Raises:
        ConfigError: On bad settings (checked before any episode runs).
        EstimatorError: With ``cfg.fail_fast``, the first episode the estimator failed (with its traceback).
        DatasetError: ``out_dir`` not empty without ``overwrite``, a file, or not writable.
    """
    preflight(Backend.of(cfg))  # before the output is touched
    if out_dir is not None:
        prepare_out_dir(out_dir, overwrite=overwrite)
    if cfg.episodes < 1:
        raise ConfigError(f"episodes must be >= 1, got {cfg.episodes!r}")
    if cfg.seed < 0:
        raise ConfigError(f"seed must be >= 0, got {cfg.seed!r}")
    check_timeout(cfg.timeout)
    check_planner_obstacles(cfg.planner_obstacles)
    parse_reobserve(cfg.reobserve)
    check_choice("GraspRunConfig.reobserve_update", cfg.reobserve_update, UPDATES)
    check_choice("GraspRunConfig.reobserve_fusion", cfg.reobserve_fusion, FUSIONS)
    resolve_depth_sensor(cfg.depth_sensor)  # a bad name fails here, listing the sensors
    ObservationModel(profile=cfg.observation_profile)  # so does a bad profile
    EpisodeConfig.build(EpisodeConfig(), {k: v for k, v in cfg.reset_options(0, []).items()})  # validate early
    out = None if out_dir is None else Path(out_dir)
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
        if cfg.save_observations:
            write_observation_models(load_objects(cfg.objects, cfg.units, cfg.scale),
                                     CameraModel.default(cfg.width, cfg.height), out / OBSERVATIONS_FOLDER)
    t0 = time.perf_counter()
    rows: list[dict] = []
    bar = None
    if progress:
        bar = tqdm(total=cfg.episodes, unit="episode", desc="grasp", dynamic_ncols=True, file=sys.stderr)
    stats = RunStats()
    lost: BackendError | None = None
    try:
        _run_episodes(cfg, out, rows, bar, stats)
    except BackendError as exc:
        if not stats.failures or not rows:
            raise
        lost = exc  # the finished episodes are written first
    finally:
        if bar is not None:
            bar.close()
    rows.sort(key=lambda r: r["episode"])
    summary = run_summary.summarize(rows)
    summary["config"] = cfg.to_dict()
    summary["estimator_label"] = rows[0]["estimator_label"]  # from the estimator the episodes ran
    summary["planner_obstacles"] = cfg.planner_obstacles
    summary["wall_s_total"] = time.perf_counter() - t0
    summary["command_line"] = list(command_line) if command_line is not None else None
    summary["run"] = {**stats.record(cfg.workers), "backend": cfg.backend, "ray_address": cfg.ray_address,
                      "retried": stats.retried, "lost_episodes": sorted(f.unit for f in stats.failures)}
    report = GraspRunReport(rows, summary, out, stats)
    if parse_reobserve(cfg.reobserve).active:
        summary["stages"] = write_stage_outputs(rows, out)
    if out is not None:
        run_summary.write_run_outputs(report.rows, report.summary, out)
        if "stages" in summary:
            with (out / "summary.md").open("a", encoding="utf-8") as f:
                f.write("\n## Pose error per look\n\n" + stage_markdown(summary["stages"]))
    if lost is not None:
        ids = summary["run"]["lost_episodes"]
        raise BackendError(f"{len(ids)} of {cfg.episodes} episodes were lost with their workers more than "
                           f"{Backend.of(cfg).retries} time(s) (episodes "
                           f"{', '.join(map(str, ids[:20]))}); the outputs"
                           f"{'' if out is None else ' in ' + repr(str(out))} cover the other {len(rows)} "
                           f"(summary.json: run.lost_episodes): run again for the full count") from lost
    return report


def _run_episodes(cfg: GraspRunConfig, out: Path | None, rows: list[dict], bar, stats: RunStats) -> None:
    """Run every episode where ``cfg.backend`` says, appending its row to ``rows`` as it finishes.

    Raises:
        EstimatorError: With ``cfg.fail_fast``, at the first estimator fault.
        BackendError: Episodes lost beyond the retries (after every other one finished).
    """
    backend = Backend.of(cfg)
    out_str = None if out is None else str(out.resolve())  # absolute: a worker's working folder may differ
    ctx = _make_context(cfg, out_str) if backend.in_process(cfg.episodes) else None
    init_args: tuple = ()
    if ctx is None:
        resolved = cfg.to_dict()
        resolved["targets"] = _resolve_targets(cfg)  # once here, not in every worker
        init_args = (resolved, out_str)
    try:
        fn = _run_one if ctx is None else functools.partial(_run_one, ctx=ctx)
        for row in run_units(fn, list(range(cfg.episodes)), backend, init=_worker_init, init_args=init_args,
                             stats=stats):
            rows.append(row)
            _tick(bar, rows)
            _check_fail_fast(cfg, row)
    finally:
        if ctx is not None:
            ctx["task"].close()


def check_planner_obstacles(value: Any) -> str:
    """``value`` if it is a planner obstacle source (:data:`simtest.envs.planner.OBSTACLE_SOURCES`).

    Raises:
        ConfigError: Naming the field, the bad value and the allowed ones.
    """
    if value not in OBSTACLE_SOURCES:
        raise ConfigError(f"GraspRunConfig.planner_obstacles must be one of {', '.join(OBSTACLE_SOURCES)} "
                          f"(sim: the simulator's geometry; observed: the observation's depth image); got {value!r}")
    return value


def _check_fail_fast(cfg: GraspRunConfig, row: dict) -> None:
    """With ``cfg.fail_fast``, raise :class:`EstimatorError` (with the traceback) for an estimator fault."""
    if cfg.fail_fast and row["reason"] in ESTIMATOR_FAULTS:
        trace = str(row.get("trace") or row.get("traceback") or "").rstrip()
        raise EstimatorError(f"{cfg.estimator} failed in episode {row['episode']} (seed {row['seed']}, "
                             f"{row['reason']}): {row['error']}" + (f"\n{trace}" if trace else ""))


def _tick(bar, rows: list[dict]) -> None:
    if bar is None:
        return
    ok = sum(bool(r["success"]) for r in rows)
    bar.set_postfix(success=f"{ok}/{len(rows)}")
    bar.update(1)


def write_stage_outputs(rows: list[dict], out: Path | None) -> list[dict]:
    """The per-stage error table of a run with re-observation (:func:`simtest.envs.reobserve.stage_table`); with
    ``out``, every look as a row of ``stages.csv`` (:data:`~simtest.envs.reobserve.STAGE_COLUMNS`; m, deg)."""
    looks = [{"episode": r["episode"], "seed": r["seed"], "target_name": r["target_name"], **st}
             for r in rows for st in r.get("stages", ())]
    if out is not None:
        with (out / "stages.csv").open("w", newline="", encoding="utf-8") as f:
            w = csv.DictWriter(f, fieldnames=STAGE_COLUMNS, extrasaction="ignore")
            w.writeheader()
            for r in looks:
                w.writerow({k: ("" if isinstance(v, float) and not math.isfinite(v) else v) for k, v in r.items()})
    return stage_table(looks)
