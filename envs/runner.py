"""Many closed-loop episodes: seeding, worker processes, ``episodes.csv``, summaries, videos, noise sweeps.

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
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from simtest.backend import Backend, BackendError, RunStats, preflight, run_units
from simtest.errors import ConfigError, EstimatorError
from simtest.metrics.intervals import wilson_interval
from simtest.estimators.guard import DEFAULT_TIMEOUT_S, check_timeout
from simtest.rng import child_sequence
from simtest.io.files import jsonable

__all__ = ["GraspRunConfig", "GraspRunReport", "episode_seed", "wilson_interval", "run_grasp_episodes",
           "summarize", "noise_sweep", "NoiseSweepResult", "write_video"]

#: Columns of ``episodes.csv`` (units: m, deg, s).
CSV_COLUMNS = ["episode", "seed", "target_obj_id", "target_name", "success", "reason", "add_s", "re_deg",
               "re_sym_deg", "te", "mssd", "estimate_s", "wall_s", "sim_s", "lift_height", "occlusion",
               "occluded_fraction", "visible_pixels", "grasp_index", "approach_tilt_deg", "error", "traceback",
               "warnings", "planner_obstacles"]
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

    def reset_options(self, index: int, target_list: Sequence) -> dict:
        opts: dict[str, Any] = {"objects": self.objects, "n_distractors": self.n_distractors,
                                "occlusion": self.occlusion, "depth_noise": self.depth_noise,
                                "corruption": None if self.weather is None else
                                {"weather": self.weather, "severity": self.severity}}
        if target_list:
            opts["target"] = target_list[index % len(target_list)]
        return opts

    def to_dict(self) -> dict:
        return {k: (list(v) if isinstance(v, tuple) else v) for k, v in self.__dict__.items()}


@dataclass
class GraspRunReport:
    """Rows and summary of a run (see :func:`summarize` for the summary's keys)."""

    rows: list[dict]
    summary: dict
    out_dir: Path | None = None
    run: RunStats = field(default_factory=RunStats)  # what the back end did (episodes retried, lost)

    def table(self) -> str:
        return summary_markdown(self.summary)

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
        from simtest.envs.grasp_env import load_objects

        return [o.obj_id for o in load_objects(cfg.objects, cfg.units, cfg.scale) if o.graspable]
    return list(cfg.targets)


# --- one episode (in this process or a worker) -----------------------------------------------------------
_WORKER: dict = {}


def _worker_init(cfg_dict: dict, out_dir: str | None) -> None:
    cfg = GraspRunConfig(**{**cfg_dict, "targets": tuple(cfg_dict["targets"])})
    from simtest.backend.threads import worker_threads

    worker_threads(cfg.workers, cfg.ray_address, apply=True)  # its share of the cores
    _WORKER.clear()
    _WORKER.update(_make_context(cfg, out_dir))


def _make_context(cfg: GraspRunConfig, out_dir: str | None) -> dict:
    from simtest.envs.grasp_env import PandaGraspEnv
    from simtest.envs.planner import GraspPlanner
    from simtest.estimators.base import estimator_label
    from simtest.estimators.registry import load_estimator

    env = PandaGraspEnv(width=cfg.width, height=cfg.height, objects=cfg.objects, object_units=cfg.units,
                        object_scale=cfg.scale, depth_sensor=cfg.depth_sensor,
                        render_width=max(cfg.width, 320), render_height=max(cfg.height, 240))
    est = load_estimator(cfg.estimator, **cfg.estimator_options)
    return {"cfg": cfg, "env": env, "estimator": est, "targets": _resolve_targets(cfg), "out": out_dir,
            "planner": GraspPlanner(obstacles=cfg.planner_obstacles), "label": estimator_label(cfg.estimator, est)}


def _run_one(index: int, ctx: dict | None = None) -> dict:
    from simtest.envs.episode import run_episode

    ctx = ctx if ctx is not None else _WORKER
    cfg: GraspRunConfig = ctx["cfg"]
    seed = episode_seed(cfg.seed, index)
    record = bool(cfg.video and ctx["out"] is not None and index < cfg.video_episodes)
    res = run_episode(ctx["env"], ctx["estimator"], ctx["planner"], seed=seed,
                      options=cfg.reset_options(index, ctx["targets"]), record=record, record_every=RECORD_EVERY,
                      timeout=cfg.timeout)
    row = {"episode": index, **res.to_row(), "estimator_label": ctx["label"]}  # the label is not a CSV column
    if record and res.frames:
        from simtest.envs.grasp_env import CONTROL_DT

        path = Path(ctx["out"]) / "videos" / f"episode_{index:04d}_{res.target_name}_{res.reason}.gif"
        write_video(res.frames, path, fps=1.0 / (CONTROL_DT * RECORD_EVERY))  # real time
    return row


def write_video(frames: Sequence[np.ndarray], path: str | Path, fps: float = 10.0) -> Path:
    """Write frames (H, W, 3) uint8 as an MP4 if an ffmpeg backend is installed, else as a GIF.

    Args:
        frames: The frames.
        path: Output path (its suffix is replaced by ``.mp4`` or ``.gif``).
        fps: Frames per second of playback; a GIF stores ``1000 / fps`` ms per frame (imageio's GIF writer
            takes ``duration`` in milliseconds), rounded by the format to 10 ms.

    Returns:
        The path written (suffix ``.mp4`` or ``.gif``).
    """
    import imageio.v2 as imageio

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        import imageio_ffmpeg  # noqa: F401

        path = path.with_suffix(".mp4")
        imageio.mimwrite(path, list(frames), fps=fps, macro_block_size=1)
    except ImportError:
        path = path.with_suffix(".gif")
        imageio.mimwrite(path, [f[::2, ::2] if f.shape[1] > 640 else f for f in frames],
                         duration=1000.0 / fps, loop=0)
    return path


def run_grasp_episodes(cfg: GraspRunConfig, out_dir: str | Path | None = None, *, progress: bool = True,
                       command_line: Sequence[str] | None = None, overwrite: bool = False) -> GraspRunReport:
    """Run ``cfg.episodes`` closed-loop episodes and (with ``out_dir``) write the outputs.

    Outputs: ``episodes.csv`` (one row per episode, :data:`CSV_COLUMNS`), ``summary.json`` and
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
        from simtest.io.files import prepare_out_dir

        prepare_out_dir(out_dir, overwrite=overwrite)
    if cfg.episodes < 1:
        raise ConfigError(f"episodes must be >= 1, got {cfg.episodes!r}")
    if cfg.seed < 0:
        raise ConfigError(f"seed must be >= 0, got {cfg.seed!r}")
    check_timeout(cfg.timeout)
    check_planner_obstacles(cfg.planner_obstacles)
    from simtest.envs.observation import resolve_depth_sensor

    resolve_depth_sensor(cfg.depth_sensor)  # a bad name fails here, listing the sensors
    from simtest.envs.grasp_env import EpisodeConfig

    EpisodeConfig.build(EpisodeConfig(), {k: v for k, v in cfg.reset_options(0, []).items()})  # validate early
    out = None if out_dir is None else Path(out_dir)
    if out is not None:
        out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    rows: list[dict] = []
    bar = None
    if progress:
        from tqdm import tqdm

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
    summary = summarize(rows)
    summary["config"] = cfg.to_dict()
    summary["estimator_label"] = rows[0]["estimator_label"]  # from the estimator the episodes ran
    summary["planner_obstacles"] = cfg.planner_obstacles
    summary["wall_s_total"] = time.perf_counter() - t0
    summary["command_line"] = list(command_line) if command_line is not None else None
    summary["run"] = {**stats.record(cfg.workers), "backend": cfg.backend, "ray_address": cfg.ray_address,
                      "retried": stats.retried, "lost_episodes": sorted(f.unit for f in stats.failures)}
    report = GraspRunReport(rows, summary, out, stats)
    if out is not None:
        _write_outputs(report, out)
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
            ctx["env"].close()


def check_planner_obstacles(value: Any) -> str:
    """``value`` if it is a planner obstacle source (:data:`simtest.envs.planner.OBSTACLE_SOURCES`).

    Raises:
        ConfigError: Naming the field, the bad value and the allowed ones.
    """
    from simtest.envs.planner import OBSTACLE_SOURCES

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


def _nanmedian(values: list[float]) -> float | None:
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], dtype=np.float64)
    return float(np.median(v)) if len(v) else None


def summarize(rows: list[dict]) -> dict:
    """Success rate with a 95 % Wilson interval, per object and per failure reason, and pose-error medians.

    Returns:
        ``{"episodes", "successes", "success_rate", "ci95": [lo, hi], "by_object": {name: {"obj_id", "n",
        "successes", "success_rate", "ci95"}}, "by_reason": {reason: count}, "median_add_s", "median_re_deg",
        "median_te", "median_mssd", "median_wall_s", "median_estimate_s"}`` (errors in m / deg, times in s;
        the rotation error is ``re_sym``, the smallest over the object's symmetries, as in ``simtest eval``).
    """
    from simtest.envs.episode import FAILURE_REASONS

    n = len(rows)
    k = sum(bool(r["success"]) for r in rows)
    lo, hi = wilson_interval(k, n)
    by_obj: dict[str, dict] = {}
    for r in rows:
        e = by_obj.setdefault(r["target_name"], {"obj_id": int(r["target_obj_id"]), "n": 0, "successes": 0})
        e["n"] += 1
        e["successes"] += int(bool(r["success"]))
    for e in by_obj.values():
        e["success_rate"] = e["successes"] / e["n"]
        e["ci95"] = list(wilson_interval(e["successes"], e["n"]))
    by_obj = dict(sorted(by_obj.items(), key=lambda kv: kv[1]["obj_id"]))
    reasons = {reason: sum(r["reason"] == reason for r in rows) for reason in FAILURE_REASONS}
    return {
        "episodes": n, "successes": k, "success_rate": k / n if n else 0.0, "ci95": [lo, hi],
        "by_object": by_obj, "by_reason": reasons,
        "median_add_s": _nanmedian([r["add_s"] for r in rows]),
        "median_re_deg": _nanmedian([r.get("re_sym_deg", r["re_deg"]) for r in rows]),
        "median_te": _nanmedian([r["te"] for r in rows]),
        "median_mssd": _nanmedian([r["mssd"] for r in rows]),
        "median_wall_s": _nanmedian([r["wall_s"] for r in rows]),
        "median_estimate_s": _nanmedian([r["estimate_s"] for r in rows]),
    }


def _pct(x: float) -> str:
    return f"{100 * x:.1f}%"


def summary_markdown(s: dict) -> str:
    """The summary as Markdown tables."""
    lo, hi = s["ci95"]
    cfg = s.get("config") or {}
    lines = ["# Closed-loop grasping", ""]
    if cfg:
        opts = ", ".join(f"{k}={v}" for k, v in (cfg.get("estimator_options") or {}).items())
        lines += [f"Estimator `{s.get('estimator_label') or cfg.get('estimator')}`" + (f" ({opts})" if opts else "") +
                  f", objects `{cfg.get('objects')}`, occlusion {cfg.get('occlusion')}, "
                  f"weather {cfg.get('weather') or 'none'}"
                  + (f" (severity {cfg.get('severity')})" if cfg.get("weather") else "")
                  + f", depth noise {cfg.get('depth_noise') or 'none'}"
                  f", depth sensor {cfg.get('depth_sensor', 'none')}"
                  f", distractors {cfg.get('n_distractors')}, "
                  f"seed {cfg.get('seed')}, planner obstacles {cfg.get('planner_obstacles', 'sim')}.", ""]
    if s.get("command_line"):
        lines += ["```", " ".join(s["command_line"]), "```", ""]
    lines += [f"**Success: {s['successes']}/{s['episodes']} = {_pct(s['success_rate'])}** "
              f"(95% Wilson CI {_pct(lo)} - {_pct(hi)})", ""]

    def fmt(v: float | None, scale: float = 1.0, digits: int = 1) -> str:
        return "-" if v is None else f"{v * scale:.{digits}f}"

    lines += ["| median ADD(-S) mm | median re_sym deg | median te mm | median MSSD mm | median episode s |",
              "|---:|---:|---:|---:|---:|",
              f"| {fmt(s['median_add_s'], 1000)} | {fmt(s['median_re_deg'])} | {fmt(s['median_te'], 1000)} | "
              f"{fmt(s['median_mssd'], 1000)} | {fmt(s['median_wall_s'], 1, 2)} |", ""]
    lines += ["## Per object", "", "| obj_id | object | episodes | success | 95% CI |", "|---:|---|---:|---:|---|"]
    for name, e in s["by_object"].items():
        lines.append(f"| {e['obj_id']} | {name} | {e['n']} | {_pct(e['success_rate'])} | "
                     f"{_pct(e['ci95'][0])} - {_pct(e['ci95'][1])} |")
    lines += ["", "## Outcomes", "", "| reason | episodes |", "|---|---:|"]
    for reason, count in s["by_reason"].items():
        lines.append(f"| {reason} | {count} |")
    return "\n".join(lines) + "\n"


def _write_outputs(report: GraspRunReport, out: Path) -> None:
    from simtest.io.files import atomic_write_json

    tmp = out / ".episodes.csv.partial"
    with tmp.open("w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=CSV_COLUMNS, extrasaction="ignore")
        w.writeheader()
        for r in report.rows:
            w.writerow({k: ("" if isinstance(v, float) and not math.isfinite(v) else v) for k, v in r.items()})
    tmp.replace(out / "episodes.csv")
    atomic_write_json(out / "summary.json", jsonable(report.summary))
    (out / "summary.md").write_text(summary_markdown(report.summary), encoding="utf-8")


# --- noise sweep ---------------------------------------------------------------------------------------------
@dataclass
class NoiseSweepResult:
    """Success against oracle pose error: one row per (translation mm, rotation deg) point."""

    rows: list[dict]
    episodes_per_point: int

    def table(self) -> str:
        """Markdown: translation error (mm), rotation error (deg), success with 95 % Wilson CI, and the
        most common failure reasons."""
        lines = ["| translation error mm | rotation error deg | success | 95% CI | failures |",
                 "|---:|---:|---:|---|---|"]
        for r in self.rows:
            fails = ", ".join(f"{k} {v}" for k, v in sorted(r["by_reason"].items(), key=lambda kv: -kv[1])
                              if k != "none" and v)
            lines.append(f"| {r['trans_mm']:g} | {r['rot_deg']:g} | {r['successes']}/{r['episodes']} = "
                         f"{_pct(r['success_rate'])} | {_pct(r['ci95'][0])} - {_pct(r['ci95'][1])} | "
                         f"{fails or '-'} |")
        return "\n".join(lines) + "\n"


def noise_sweep(trans_mm: Sequence[float] = (0, 5, 10, 20, 30), rot_deg: Sequence[float] = (0, 5, 10, 20, 30), *,
                episodes: int = 27, seed: int = 0, objects: str = "builtin", targets: tuple = ("all",),
                n_distractors: int = 0, width: int = 160, height: int = 120, workers: int = 1,
                progress: bool = True, out_dir: str | Path | None = None) -> NoiseSweepResult:
    """Grasp success of the ``oracle`` with pose errors of exact size: two curves, translation error (rotation
    0) and rotation error (translation 0).

    The oracle runs in ``"fixed"`` mode: every estimate is off by exactly ``trans_mm`` millimetres in a random
    direction and ``rot_deg`` degrees about a random axis (seeded per episode). Every point uses the same
    episodes (same seeds, scenes and targets), so the curves are paired comparisons.

    Args:
        trans_mm: Translation errors, millimetres (run with zero rotation error).
        rot_deg: Rotation errors, degrees (run with zero translation error).
        episodes: Episodes per point.
        seed, objects, targets, n_distractors, width, height, workers: As in :class:`GraspRunConfig`.
        out_dir: If given, each point's outputs go to ``out_dir/t<mm>_r<deg>/`` and the table to
            ``out_dir/noise_sweep.md``.
    """
    points = [(float(t), 0.0) for t in trans_mm] + [(0.0, float(r)) for r in rot_deg if float(r) != 0.0
                                                    or not any(float(t) == 0.0 for t in trans_mm)]
    rows = []
    for t, r in points:
        cfg = GraspRunConfig(estimator="oracle", estimator_options={"trans_noise_mm": t, "rot_noise_deg": r,
                                                                   "rot_noise_mode": "fixed"},
                             episodes=episodes, seed=seed, objects=objects, targets=tuple(targets),
                             n_distractors=n_distractors, width=width, height=height, workers=workers)
        sub = None if out_dir is None else Path(out_dir) / f"t{t:g}_r{r:g}"
        rep = run_grasp_episodes(cfg, sub, progress=progress)
        s = rep.summary
        rows.append({"trans_mm": t, "rot_deg": r, "episodes": s["episodes"], "successes": s["successes"],
                     "success_rate": s["success_rate"], "ci95": s["ci95"], "by_reason": s["by_reason"]})
    result = NoiseSweepResult(rows, episodes)
    if out_dir is not None:
        Path(out_dir).mkdir(parents=True, exist_ok=True)
        (Path(out_dir) / "noise_sweep.md").write_text(result.table(), encoding="utf-8")
    return result
