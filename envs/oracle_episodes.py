"""Closed-loop episodes of one target each, the unit of work of tolerance maps and metric calibration
(:mod:`simtest.envs.tolerance`, :mod:`simtest.envs.calibration`): by default the ``oracle`` with an error chosen
per episode, or a real estimator (``OracleUnit.estimator``, any name ``simtest grasp --estimator`` takes).

Each unit is one episode of one target object; a worker keeps one grasp task (one compiled model of the object
set, one renderer), one planner, and makes a fresh oracle per unit (a real estimator is made once per worker
and reset before every unit; its randomness is seeded by the observation), so the result of a unit depends on
the unit alone: the same unit gives the same row on any worker, with any number of workers and on either
back end (``local`` processes or ``ray`` tasks, :mod:`simtest.backend`). Every episode runs through
:func:`simtest.envs.episode.run_episode`, the loop of ``simtest grasp``.

The oracle reads no image; the wrist camera still renders one small observation per episode (and the
occluder tuning at L1-L3 renders a few more): at 64 x 48 pixels that is a small part of an episode, which is
mostly physics (about 10 simulated seconds). A real estimator needs the size it was made for (320 x 240 for
the shipped networks).
"""

from __future__ import annotations

import functools
import sys
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from tqdm import tqdm

from simtest.backend import Backend, RunStats, preflight, run_units
from simtest.envs.episode import pick_estimate, run_episode
from simtest.envs.observation import ObservationModel
from simtest.envs.options import load_objects
from simtest.envs.planner import GraspPlanner
from simtest.envs.task import GraspTask
from simtest.errors import ConfigError
from simtest.estimators.base import reset_estimator
from simtest.estimators.guard import DEFAULT_TIMEOUT_S
from simtest.estimators.oracle import OracleEstimator
from simtest.estimators.registry import load_estimator
from simtest.metrics.bop19 import VSD_DELTA, VSD_TAUS
from simtest.metrics.pose import mspd, vsd
from simtest.backend.threads import worker_threads
from simtest.rng import child_sequence

__all__ = ["OracleUnit", "EpisodeSetup", "run_oracle_units", "episode_seed_of", "check_objects"]


@dataclass(frozen=True)
class OracleUnit:
    """One episode: target ``obj_id``, env seed ``seed``, occlusion level, the estimator (``"oracle"``, or a
    name ``simtest grasp --estimator`` takes) with its options, and tags copied into the row (e.g. the axis and
    magnitude of a tolerance cell)."""

    obj_id: int
    seed: int
    options: tuple = ()  # (key, value) pairs of the estimator's options
    occlusion: str = "L0"
    tags: tuple = ()  # (key, value) pairs added to the row
    estimator: str = "oracle"


@dataclass(frozen=True)
class EpisodeSetup:
    """Where and how the units run.

    Attributes:
        objects, units, scale: Object set and its mesh units (see :func:`simtest.objects.load_object_set`).
        width, height: Wrist camera size, pixels (the oracle reads no image: small is fast).
        workers, backend, ray_address: Where the units run (:class:`simtest.backend.Backend`).
        timeout: Time limit of the estimator call, seconds.
        mspd: Also compute MSPD (pixels of a 640 px wide image) of the estimate used (``mspd`` in the row).
        vsd: Also compute VSD (BOP19: ``delta`` 15 mm, mean of the errors over ``tau`` = 0.05..0.5 of the
            diameter, in [0, 1]) of the estimate used against the observation's depth (``vsd`` in the row, and
            ``vsd_taus``: the errors per ``tau``); NaN without an estimate.
    """

    objects: str = "builtin-small"
    units: str = "auto"
    scale: float = 1.0
    width: int = 64
    height: int = 48
    workers: int = 1
    backend: str = "local"
    ray_address: str | None = None
    timeout: float | None = DEFAULT_TIMEOUT_S
    mspd: bool = False
    vsd: bool = False

    def record(self) -> dict:
        """The fields as plain values for a run's JSON record (``vsd`` only when on, so the records of oracle
        runs stay as they were)."""
        return {k: v for k, v in self.__dict__.items() if k != "vsd" or v}


def episode_seed_of(seed: int, *key: int) -> int:
    """The env seed (uint32) of the episode at ``key`` below master ``seed`` (``SeedSequence`` child)."""
    return int(child_sequence(seed, *key).generate_state(1)[0])


def check_objects(setup: EpisodeSetup, targets: Sequence) -> list:
    """The graspable objects of ``setup.objects`` (all, or the ``targets`` given as obj_ids or names).

    Raises:
        ConfigError: A target that is not a graspable object of the set (the allowed ones are listed).
    """
    objs = [o for o in load_objects(setup.objects, setup.units, setup.scale) if o.graspable]
    if not targets:
        return objs
    out = []
    for t in targets:
        hit = [o for o in objs if o.obj_id == t or o.name == t or str(o.obj_id) == str(t)]
        if not hit:
            raise ConfigError(f"object {t!r} is not a graspable object of {setup.objects!r}; allowed: "
                              f"{', '.join(f'{o.obj_id} ({o.name})' for o in objs)}")
        out.append(hit[0])
    return out


class _Recording:
    """The oracle, keeping what it was given and what it returned (for errors the episode does not compute)."""

    needs_gt = True
    needs_targets = False
    needs_depth = False

    def __init__(self, inner: Any) -> None:
        self.inner = inner
        self.last: tuple | None = None

    def estimate(self, observation):
        out = self.inner.estimate(observation)
        self.last = (observation, out)
        return out


class _Watched:
    """A real estimator seen through: its own declarations (``needs_gt_masks``, ``needs_depth``, ...) and
    ``last_failures`` read through, and of its first call the observation, the target's ground-truth
    ``(R, t)`` in the camera frame at the capture (read from the task: the estimator is not given it) and what
    it returned."""

    def __init__(self, inner: Any, task: GraspTask) -> None:
        self.inner, self.task = inner, task
        self.last: tuple | None = None

    def __getattr__(self, name: str) -> Any:
        if name in ("inner", "task", "last"):
            raise AttributeError(name)
        return getattr(self.inner, name)

    def estimate(self, observation):
        if self.last is None:
            T = self.task.current_info()["T_cam_obj"][self.task.grasp_scene.target_instance]
            self.last = (observation, (T[:3, :3].copy(), T[:3, 3].copy()), [])
        out = self.inner.estimate(observation)
        if self.last[0] is observation:
            self.last = (*self.last[:2], out)
        return out


_WORKER: dict = {}


def _make_context(setup: EpisodeSetup) -> dict:
    task = GraspTask(width=setup.width, height=setup.height, episode={"objects": setup.objects},
                     observation=ObservationModel(), object_units=setup.units, object_scale=setup.scale)
    return {"setup": setup, "task": task, "planner": GraspPlanner()}


def _worker_init(setup: EpisodeSetup) -> None:
    worker_threads(setup.workers, setup.ray_address, apply=True)
    _WORKER.clear()
    _WORKER.update(_make_context(setup))


def _mspd_of(obs, estimates: list, obj, width: int) -> float:
    """MSPD (pixels of a 640 px wide image) of the target's estimate, NaN without one."""
    if not estimates or obs.gt_poses is None:
        return float("nan")
    e = estimates[0]
    R_g, t_g = obs.gt_poses[0]
    U, _, Vt = np.linalg.svd(np.asarray(e.R, dtype=np.float64))
    return mspd(U @ Vt, e.t, R_g, t_g, obs.K, np.asarray(obj.vertices), obj.symmetry_transforms(),
                image_width=width)


def _estimator(ctx: dict, unit: OracleUnit) -> _Watched:
    """The worker's instance of ``unit``'s estimator (made at its first unit), reset, seen through."""
    key = (unit.estimator, unit.options)
    made = ctx.setdefault("estimators", {})
    if key not in made:
        made[key] = load_estimator(unit.estimator, **dict(unit.options))
    reset_estimator(made[key])
    return _Watched(made[key], ctx["task"])


def _used_errors(watched: _Watched, obj, setup: EpisodeSetup) -> dict:
    """MSPD and VSD (with ``setup.vsd``) of the estimate the episode used (the best valid one of the target,
    :func:`simtest.envs.episode.pick_estimate`); NaN without one."""
    nan = float("nan")
    out = {"mspd": nan, **({"vsd": nan, "vsd_taus": ""} if setup.vsd else {})}
    if watched.last is None:
        return out
    obs, (R_g, t_g), elements = watched.last
    chosen = pick_estimate(list(elements or []), int(obj.obj_id), set(watched.task.objects.ids))[0]
    if chosen is None:
        return out
    U, _, Vt = np.linalg.svd(np.asarray(chosen.R, dtype=np.float64))
    R_e, t_e = U @ Vt, np.asarray(chosen.t, dtype=np.float64)
    if setup.mspd:
        out["mspd"] = mspd(R_e, t_e, R_g, t_g, obs.K, np.asarray(obj.vertices), obj.symmetry_transforms(),
                           image_width=setup.width)
    if setup.vsd and obs.depth is not None:
        e = vsd(R_e, t_e, R_g, t_g, obs.depth, obs.K, obj, VSD_DELTA, VSD_TAUS, float(obj.diameter))
        out["vsd"], out["vsd_taus"] = float(np.mean(e)), " ".join(f"{x:.4f}" for x in e)
    return out


def _run_unit(unit: OracleUnit, ctx: dict | None = None) -> dict:
    ctx = ctx if ctx is not None else _WORKER
    setup: EpisodeSetup = ctx["setup"]
    if unit.estimator != "oracle":
        return _run_estimator_unit(unit, ctx)
    est = _Recording(OracleEstimator(**dict(unit.options)))
    options = {"objects": setup.objects, "target": unit.obj_id, "n_distractors": 0, "occlusion": unit.occlusion,
               "corruption": None, "depth_noise": None}
    res = run_episode(ctx["task"], est, ctx["planner"], seed=unit.seed, options=options, timeout=setup.timeout)
    row = {**dict(unit.tags), **res.to_row()}
    row.pop("trace", None)
    if setup.mspd:
        obs, out = est.last if est.last is not None else (None, [])
        row["mspd"] = _mspd_of(obs, out, ctx["task"].target_obj, setup.width) if obs is not None \
            else float("nan")
    return row


def _run_estimator_unit(unit: OracleUnit, ctx: dict) -> dict:
    """One episode of a real estimator: the row of :func:`_run_unit` plus ``estimator`` and, with the setup's
    switches, the MSPD and VSD of the estimate used."""
    setup: EpisodeSetup = ctx["setup"]
    est = _estimator(ctx, unit)
    options = {"objects": setup.objects, "target": unit.obj_id, "n_distractors": 0, "occlusion": unit.occlusion,
               "corruption": None, "depth_noise": None}
    res = run_episode(ctx["task"], est, ctx["planner"], seed=unit.seed, options=options, timeout=setup.timeout)
    row = {"estimator": unit.estimator, **dict(unit.tags), **res.to_row()}
    row.pop("trace", None)
    row.update(_used_errors(est, ctx["task"].target_obj, setup))
    return row


def run_oracle_units(setup: EpisodeSetup, units: Sequence[OracleUnit], *, progress: bool = True,
                     desc: str = "episodes", stats: RunStats | None = None) -> Iterator[dict]:
    """Run every unit where ``setup`` says and yield its row (the episode's :class:`EpisodeResult` fields and
    the unit's tags) as it finishes, in the order units finish.

    Raises:
        ConfigError: ``setup`` asks for no workers.
        BackendError: Units lost with their workers beyond the retries.
    """
    if setup.workers < 1:
        raise ConfigError(f"workers must be >= 1, got {setup.workers!r}")
    backend = Backend(setup.backend, setup.workers, setup.ray_address)
    preflight(backend)
    bar = None
    if progress:
        bar = tqdm(total=len(units), unit="episode", desc=desc, dynamic_ncols=True, file=sys.stderr)
    ctx = _make_context(setup) if backend.in_process(len(units)) else None
    fn = _run_unit if ctx is None else functools.partial(_run_unit, ctx=ctx)
    ok = 0
    try:
        for row in run_units(fn, list(units), backend, init=_worker_init, init_args=(setup,), stats=stats):
            ok += bool(row["success"])
            if bar is not None:
                bar.set_postfix(success=f"{ok}/{bar.n + 1}")
                bar.update(1)
            yield row
    finally:
        if bar is not None:
            bar.close()
        if ctx is not None:
            ctx["task"].close()
