"""Closed-loop episodes of the ``oracle`` with an error chosen per episode: the unit of work of tolerance maps
and metric calibration (:mod:`simtest.envs.tolerance`, :mod:`simtest.envs.calibration`).

Each unit is one episode of one target object with its own oracle options; a worker keeps one grasp task (one
compiled model of the object set, one small renderer), one planner, and makes a fresh oracle per unit, so the
result of a unit depends on the unit alone: the same unit gives the same row on any worker, with any number
of workers and on either back end (``local`` processes or ``ray`` tasks, :mod:`simtest.backend`).

The oracle reads no image; the wrist camera still renders one small observation per episode (and the
occluder tuning at L1-L3 renders a few more): at 64 x 48 pixels that is a small part of an episode, which is
mostly physics (about 10 simulated seconds).
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
from simtest.envs.episode import run_episode
from simtest.envs.observation import ObservationModel
from simtest.envs.options import load_objects
from simtest.envs.planner import GraspPlanner
from simtest.envs.task import GraspTask
from simtest.errors import ConfigError
from simtest.estimators.guard import DEFAULT_TIMEOUT_S
from simtest.estimators.oracle import OracleEstimator
from simtest.metrics.pose import mspd
from simtest.backend.threads import worker_threads
from simtest.rng import child_sequence

__all__ = ["OracleUnit", "EpisodeSetup", "run_oracle_units", "episode_seed_of", "check_objects"]


@dataclass(frozen=True)
class OracleUnit:
    """One episode: target ``obj_id``, env seed ``seed``, occlusion level, the oracle's options and tags copied
    into the row (e.g. the axis and magnitude of a tolerance cell)."""

    obj_id: int
    seed: int
    options: tuple = ()  # (key, value) pairs of the oracle's options
    occlusion: str = "L0"
    tags: tuple = ()  # (key, value) pairs added to the row


@dataclass(frozen=True)
class EpisodeSetup:
    """Where and how the units run.

    Attributes:
        objects, units, scale: Object set and its mesh units (see :func:`simtest.objects.load_object_set`).
        width, height: Wrist camera size, pixels (the oracle reads no image: small is fast).
        workers, backend, ray_address: Where the units run (:class:`simtest.backend.Backend`).
        timeout: Time limit of the estimator call, seconds.
        mspd: Also compute MSPD (pixels of a 640 px wide image) of the estimate used (``mspd`` in the row).
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


def _run_unit(unit: OracleUnit, ctx: dict | None = None) -> dict:
    ctx = ctx if ctx is not None else _WORKER
    setup: EpisodeSetup = ctx["setup"]
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
