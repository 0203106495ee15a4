"""Clutter removal: objects in a pile or packed on the table, picked one after another until the table is clear.

The protocol of grasp-detection papers (VGN, GIGA): a *round* starts with ``n`` objects of the set on the table,

* ``"pile"``: dropped one after another in random orientations from a 0.12 m wide column above the middle of
  the table, each released 5 mm above the heap so far and given 0.6 s to fall (a box lifted away), then
  settled together;
* ``"packed"``: standing upright (:func:`~simtest.envs.scene.rest_rotation`, random yaw) side by side in the
  reachable part of the table, 5-25 mm apart (an object that finds no room in the 0.26 m square is swapped
  for another draw, up to 8 times; when none fits, the round starts with fewer, with a warning);

objects that roll off the table while settling leave the round. Each *attempt*: the wrist camera observes the
remaining objects from the observation pose (looking at the one nearest their centre), the estimator is asked
for every object it can find (no target given: the detection task; estimators with ``needs_gt_masks`` get the
visible masks and boxes of every object in view, the ``oracle`` every visible object's pose), the planner plans
a grasp for each estimate and the most graspable one is executed (the highest candidate score plus the cosine
of its approach's tilt from straight down). The object under that estimate (the instance of its ``obj_id``
nearest the estimated position) is the attempt's target: lifted 0.10 m and held 1 s it is a success and is
taken out of the workspace (parked far away, :func:`simtest.generators.settle.park`). Objects pushed off the
table are parked too (they count as not removed). A round ends when the table is clear, after 2 consecutive
failed attempts, or after ``n + 2`` attempts.

Per round: grasp success rate ``GSR = successes / attempts``, declutter rate ``DR = removed / objects``, the
attempts and their failure reasons; the run pools them with 95 % Wilson intervals
(:mod:`simtest.metrics.intervals`). Lengths in metres, angles in radians, times in seconds.
"""

from __future__ import annotations

import csv
import dataclasses
import logging
import math
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

import numpy as np

import simtest  # noqa: F401  (GL backend before mujoco)
import mujoco

from simtest import robot
from simtest.envs.episode import FAILURE_REASONS, execute_grasp, orthonormal
from simtest.envs.execution import PhaseMonitor, move_joints
from simtest.envs.options import load_objects
from simtest.envs.planner import GraspPlanner, observed_obstacles
from simtest.envs.runner import GraspRunConfig, episode_seed
from simtest.envs.scene import TARGET_REGION, GraspScene, rest_rotation, sample_grasp_spec
from simtest.envs.task import GraspTask
from simtest.errors import ConfigError
from simtest.estimators.base import Observation, gt_access
from simtest.estimators.guard import call_estimator, check_estimate
from simtest.estimators.registry import load_estimator
from simtest.generators.build_options import SettleOptions
from simtest.generators.scene_spec import ObjectPlacement, random_quat_wxyz
from simtest.generators.settle import FAR_AWAY, park, settle
from simtest.geometry import Pose
from simtest.io.bop import mask_bbox
from simtest.io.files import atomic_write_json, jsonable, prepare_out_dir
from simtest.metrics.intervals import wilson_interval
from simtest.robot import GRIPPER_OPEN, move_to, set_gripper, tcp_pose

__all__ = ["SCENES", "DeclutterTask", "RoundResult", "DeclutterReport", "run_round", "run_declutter",
           "MAX_CONSECUTIVE_FAILURES"]

#: Scene types of a round (see the module docstring).
SCENES = ("pile", "packed")
#: A round ends after this many failed attempts in a row.
MAX_CONSECUTIVE_FAILURES = 2
_log = logging.getLogger(__name__)
#: Half width of the column the pile is dropped from, m.
_PILE_HALF = 0.06
#: Half width of the square packed objects stand in, m.
_PACKED_HALF = 0.13
#: Smallest visible pixels for an object to count as in view.
_MIN_PIXELS = 20


class DeclutterTask(GraspTask):
    """A :class:`GraspTask` whose scene holds ``n`` objects and no fixed target: :meth:`start_round` builds
    it, :meth:`retarget` makes one instance the target of the success checks, :meth:`remove` takes one out."""

    def start_round(self, seed: int, scene: str, n: int, objects: str | None = None) -> int:
        """Build and settle a round's scene (``scene`` in :data:`SCENES`, ``n`` objects); returns the objects
        left on the table.

        Raises:
            ConfigError: A bad ``scene`` or ``n`` (named with the allowed values).
        """
        if scene not in SCENES:
            raise ConfigError(f"scene must be one of {', '.join(SCENES)}, got {scene!r}")
        if isinstance(n, bool) or not isinstance(n, (int, np.integer)) or not 1 <= n <= 20:
            raise ConfigError(f"objects_per_scene must be an integer in 1..20, got {n!r}")
        name = objects or self.defaults.objects
        self.reset(seed=seed, options={"objects": name, "n_distractors": 0, "occlusion": 0})
        rng = np.random.default_rng([int(seed), 7])
        builder, objs = self._builder(name), self.objects
        spec = sample_grasp_spec(builder, objs, int(objs.ids[0]), rng)
        spec = dataclasses.replace(spec, objects=tuple(_placements(builder, objs, rng, scene, int(n))))
        sim = self._model_cache(name).build(spec)
        if scene == "pile":
            _drop_one_by_one(sim, float(builder.options.room.table_height))
        settle(sim, SettleOptions(max_time=4.0, room=builder.options.room))
        if sim.model is not self.model:
            self._bind_model(sim)
        else:
            mujoco.mj_resetData(self.model, self._scratch)
            mujoco.mj_resetData(self.model, self._diffik.data)
        self.grasp_scene = GraspScene(sim, 0, -1, float(builder.options.room.table_height))
        self.occlusion = None
        self._instance_bodies = np.asarray(sim.instance_bodies, dtype=np.int64)
        self._obj_ids = tuple(int(i) for i in sim.instance_obj_ids)
        self.T_world_base = Pose(self.data.xmat[self.ids.base_body].reshape(3, 3), self.data.xpos[self.ids.base_body])
        self._T_base_world = self.T_world_base.inverse().matrix()
        self._T_world_base_m = self.T_world_base.matrix()
        self._ws_lo, self._ws_hi = self._workspace()
        remaining = self.remaining()
        self.retarget(remaining[0] if remaining else 0)
        robot.reset_arm(self.model, self.data, self.ids, None)
        self._q_cmd = self.ids.arm_q(self.data)
        self._frame = self._obs = None
        return len(remaining)

    def remaining(self) -> list[int]:
        """Instances still on the table (active and above its top)."""
        sim = self.grasp_scene.sim
        z0 = self.grasp_scene.table_height
        return [i for i in range(len(sim.instance_bodies))
                if sim.active[i] and self.data.xpos[sim.instance_bodies[i]][2] > z0 - 0.01]

    def retarget(self, instance: int) -> None:
        """Make ``instance`` the target: success checks, ground truth and the observation pose refer to it."""
        sim = self.grasp_scene.sim
        self.grasp_scene = dataclasses.replace(self.grasp_scene, target_instance=int(instance))
        self.target_obj = self.objects.get(int(sim.instance_obj_ids[instance]))
        self._target_body = sim.instance_bodies[instance]
        self._target_geoms = np.flatnonzero(sim.geom_instance == instance)
        self._geom_cat = np.zeros(self.model.ngeom, np.int8)
        self._geom_cat[self._target_geoms] = 1
        self._geom_cat[self._left_geoms] = 2
        self._geom_cat[self._right_geoms] = 4
        self.rest_height = float(self.data.xpos[self._target_body][2])
        self.q_observe = self._observation_q()

    def remove(self, instance: int) -> None:
        """Take ``instance`` out of the workspace (parked far away, no longer drawn in annotations)."""
        park(self.grasp_scene.sim, int(instance))
        mujoco.mj_forward(self.model, self.data)

    def look_at_pile(self) -> None:
        """Retarget to the remaining instance nearest the centre of the remaining ones (the observation pose
        looks at it)."""
        rem = self.remaining()
        p = self.data.xpos[self._instance_bodies[rem]]
        self.retarget(rem[int(np.argmin(np.linalg.norm(p - p.mean(axis=0), axis=1)))])


def _placements(builder, objs, rng: np.random.Generator, scene: str, n: int) -> list[ObjectPlacement]:
    """``n`` placements of a pile (dropped from a column) or of packed upright objects (see the module doc)."""
    z0 = float(builder.options.room.table_height)
    ids = [int(i) for i in objs.ids if objs.get(int(i)).graspable] or [int(i) for i in objs.ids]
    counts: dict[int, int] = {}
    out: list[ObjectPlacement] = []
    cx, cy = float(np.mean(TARGET_REGION[0])), float(np.mean(TARGET_REGION[1]))
    placed: list[tuple[np.ndarray, float]] = []
    for k in range(n):
        choices = [i for i in ids if counts.get(i, 0) < 2] or ids  # at most 2 copies: the model pool holds them
        xy = None
        for _draw in range(1 if scene == "pile" else 8):  # packed: another object when this one finds no room
            oid = int(choices[int(rng.integers(len(choices)))])
            obj = objs.get(oid)
            if scene == "pile":
                break
            R0 = rest_rotation(obj)
            yaw = float(rng.uniform(-np.pi, np.pi))
            R = np.array([[np.cos(yaw), -np.sin(yaw), 0], [np.sin(yaw), np.cos(yaw), 0], [0, 0, 1.0]]) @ R0
            v = np.asarray(obj.vertices) @ R.T
            r = float(np.linalg.norm(v[:, :2], axis=1).max())
            for _ in range(200):
                cand = np.array([cx, cy]) + rng.uniform(-_PACKED_HALF, _PACKED_HALF, 2)
                if all(np.linalg.norm(cand - q) > r + rq + rng.uniform(0.005, 0.025) for q, rq in placed):
                    xy = cand
                    break
            if xy is not None:
                break
        if scene != "pile" and xy is None:
            _log.warning("packed round: no room for object %d of %d in the %.2f m square; the round starts with %d "
                         "objects", k + 1, n, 2 * _PACKED_HALF, len(out))
            break
        counts[oid] = counts.get(oid, 0) + 1
        rgba = (*(float(c) for c in np.clip(np.asarray(obj.rgba[:3]) + rng.normal(0, 0.08, 3), 0.02, 0.98)), 1.0)
        if scene == "pile":
            xy = np.array([cx, cy]) + rng.uniform(-_PILE_HALF, _PILE_HALF, 2)
            pos = (float(xy[0]), float(xy[1]), z0 + 0.5 * float(obj.diameter) + 0.005)  # dropped later
            quat = random_quat_wxyz(rng)
        else:
            placed.append((xy, r))
            pos = (float(xy[0]), float(xy[1]), z0 - float(v[:, 2].min()) + 0.002)
            quat = tuple(float(x) for x in Pose(R, np.zeros(3)).quat_wxyz())
        out.append(ObjectPlacement(obj_id=oid, position=pos, quat_wxyz=quat, rgba=rgba,
                                   specular=float(rng.uniform(0.0, 0.4)), shininess=float(rng.uniform(0.0, 0.5)),
                                   reflectance=0.0))
    return out


def _drop_one_by_one(sim, table_z: float) -> None:
    """Drop the instances of ``sim`` (placed in the pile's column) one at a time, each released 5 mm above the
    top of the heap so far at its own x, y and orientation, with 0.6 s of physics to fall (metres, seconds)."""
    m, d = sim.model, sim.data
    n = len(sim.instance_bodies)
    start = [d.qpos[q:q + 7].copy() for q in sim.instance_qpos]
    grav = [float(m.body_gravcomp[b]) for b in sim.instance_bodies]
    for i in range(1, n):  # all but the first wait far away, floating
        q = sim.instance_qpos[i]
        d.qpos[q:q + 3] = FAR_AWAY + [10.0 * i, 20.0, 0.0]
        m.body_gravcomp[sim.instance_bodies[i]] = 1.0
    steps = int(round(0.6 / m.opt.timestep))
    for i in range(n):
        mujoco.mj_forward(m, d)
        top = max([table_z] + [float(d.xpos[sim.instance_bodies[j]][2]) + 0.5 * float(_radius(m, sim, j))
                               for j in range(i)])
        q, v = sim.instance_qpos[i], sim.instance_dofs[i]
        d.qpos[q:q + 7] = start[i]
        d.qpos[q + 2] = top + start[i][2] - table_z  # start[i][2] = table_z + half the diameter + 5 mm
        d.qvel[v:v + 6] = 0.0
        m.body_gravcomp[sim.instance_bodies[i]] = grav[i]
        mujoco.mj_step(m, d, steps)


def _radius(m: mujoco.MjModel, sim, i: int) -> float:
    """Twice the bounding radius of instance ``i``'s geoms about its body origin (about its diameter), m."""
    b = sim.instance_bodies[i]
    adr, num = int(m.body_geomadr[b]), int(m.body_geomnum[b])
    return 2.0 * float(max((np.linalg.norm(m.geom_pos[g]) + m.geom_rbound[g] for g in range(adr, adr + num)),
                           default=0.05))


@dataclass
class RoundResult:
    """One clutter-removal round.

    Attributes:
        round: Round index; ``seed``: its seed; ``scene``: ``"pile"`` or ``"packed"``.
        objects: Objects on the table after settling; ``removed``: objects grasped and taken away.
        attempts, successes: Grasp attempts and successful ones.
        gsr, dr: ``successes / attempts`` and ``removed / objects`` (0 when the denominator is 0).
        reasons: Count of each attempt outcome (``FAILURE_REASONS``; ``"none"`` = success).
        attempt_rows: Per attempt: ``attempt``, ``obj_name``, ``reason``, ``estimates``, ``candidates``
            (estimates with a feasible grasp), ``error``.
        wall_s: Wall time of the round, s.
    """

    round: int
    seed: int
    scene: str
    objects: int = 0
    removed: int = 0
    attempts: int = 0
    successes: int = 0
    reasons: dict = field(default_factory=dict)
    attempt_rows: list = field(default_factory=list)
    wall_s: float = 0.0

    @property
    def gsr(self) -> float:
        return self.successes / self.attempts if self.attempts else 0.0

    @property
    def dr(self) -> float:
        return self.removed / self.objects if self.objects else 0.0


def _observation(task: DeclutterTask, est: Any, obs: dict, seed: int, k: int) -> Observation:
    """The detection-task observation of every object in view (see the module docstring)."""
    sim = task.grasp_scene.sim
    info = task.current_info()
    seg = task.last_frame.seg
    inst = np.where(seg >= 0, sim.geom_instance[np.clip(seg, 0, None)], -1)
    vis = [i for i in task.remaining() if int((inst == i).sum()) >= _MIN_PIXELS]
    gt_masks, needs_gt = gt_access(est)
    masks = tuple(inst == i for i in vis)
    ids = tuple(int(sim.instance_obj_ids[i]) for i in vis)
    poses = tuple((info["T_cam_obj"][i][:3, :3].copy(), info["T_cam_obj"][i][:3, 3].copy()) for i in vis)
    return Observation(rgb=obs["rgb"], depth=obs["depth"], K=obs["K"], width=task.width, height=task.height,
                       objects=task.objects, target_obj_ids=ids if gt_masks and not needs_gt else None,
                       masks=masks if gt_masks and not needs_gt else None,
                       boxes=tuple(tuple(mask_bbox(m)) for m in masks) if gt_masks and not needs_gt else None,
                       gt_poses=poses if needs_gt else None, gt_obj_ids=ids if needs_gt else None,
                       scene_id=int(seed), im_id=int(k))


def _attempt(task: DeclutterTask, est: Any, planner: GraspPlanner, seed: int, k: int, timeout: float | None
             ) -> dict:
    """One attempt (observe, estimate every object, plan, grasp the most graspable); its record."""
    row = {"attempt": k, "obj_name": "", "reason": "no_estimate", "estimates": 0, "candidates": 0, "error": ""}
    task.look_at_pile()
    monitor = PhaseMonitor(task, None)
    move_joints(task, task.q_observe, monitor)
    obs = task.capture()
    elements, fault = call_estimator(est, _observation(task, est, obs, seed, k), timeout)
    if fault is not None:
        row.update(reason="estimator_timeout" if fault.kind == "timeout" else "estimator_error", error=fault.message)
        return row
    T_world_cam = Pose.from_matrix(task.current_info()["T_world_base"]) @ Pose.from_matrix(obs["T_base_cam"])
    known = set(task.objects.ids)
    best, reasons = None, []
    for i, element in enumerate(elements):
        e, why = check_estimate(element, known, index=i)
        if why is not None:
            continue
        row["estimates"] += 1
        T_world_obj = T_world_cam @ Pose(orthonormal(e.R), e.t)
        inst = _instance_of(task, int(e.obj_id), T_world_obj.t)
        if inst is None:
            continue
        task.retarget(inst)
        obj = task.target_obj
        points = observed_obstacles(task, obs, obj, T_world_obj) if planner.obstacles == "observed" else None
        res = planner.plan(task, obj, T_world_obj, obstacle_points=points)
        if res.plan is None:
            reasons.append(res.reason)
            continue
        row["candidates"] += 1
        rank = res.plan.score + float(np.cos(res.plan.approach_tilt))
        if best is None or rank > best[0]:
            best = (rank, inst, res.plan)
    if best is None:
        row["reason"] = ("ik_failure" if "ik_failure" in reasons else "no_feasible_grasp") if reasons else \
            "no_estimate"
        return row
    _, inst, plan = best
    task.retarget(inst)
    row["obj_name"] = task.target_obj.name
    row["reason"] = execute_grasp(task, plan, monitor)
    row["error"] = monitor.note
    if row["reason"] == "none":
        task.remove(inst)
    _retreat(task)
    return row


def _instance_of(task: DeclutterTask, obj_id: int, position: np.ndarray) -> int | None:
    """The remaining instance of ``obj_id`` nearest ``position`` (world, m), None without one."""
    sim = task.grasp_scene.sim
    cands = [i for i in task.remaining() if int(sim.instance_obj_ids[i]) == obj_id]
    if not cands:
        return None
    d = [float(np.linalg.norm(task.data.xpos[sim.instance_bodies[i]] - position)) for i in cands]
    return cands[int(np.argmin(d))]


def _retreat(task: DeclutterTask) -> None:
    """Raise the hand 0.15 m, open the gripper, let the pile settle 0.5 s and park what fell off the table."""
    d, ids = task.data, task.ids
    up = tcp_pose(d, ids)
    try:
        move_to(task.model, d, ids, Pose(up.R, up.t + [0.0, 0.0, 0.15]), 1.0, q_ref=d.ctrl[ids.arm_actuators].copy(),
                settle=0.2)
    except Exception:  # noqa: BLE001  an unreachable retreat: the joint move below takes the arm away anyway
        pass
    set_gripper(d, ids, GRIPPER_OPEN)
    task.advance(0.5)
    task.sync_command()
    sim = task.grasp_scene.sim
    for i in range(len(sim.instance_bodies)):
        if sim.active[i] and d.xpos[sim.instance_bodies[i]][2] < task.grasp_scene.table_height - 0.01:
            task.remove(i)


def run_round(task: DeclutterTask, estimator: Any, planner: GraspPlanner | None = None, *, seed: int,
              scene: str = "pile", n: int = 5, objects: str | None = None, index: int = 0,
              timeout: float | None = 30.0) -> RoundResult:
    """One clutter-removal round (see the module docstring)."""
    t0 = time.perf_counter()
    est = load_estimator(estimator)
    planner = planner or GraspPlanner()
    res = RoundResult(round=index, seed=int(seed), scene=scene)
    res.objects = task.start_round(seed, scene, n, objects)
    fails = 0
    while task.remaining() and res.attempts < n + 2 and fails < MAX_CONSECUTIVE_FAILURES:
        try:
            row = _attempt(task, est, planner, seed, res.attempts, timeout)
        except Exception as exc:  # noqa: BLE001  a collision on the way to the observation pose
            row = {"attempt": res.attempts, "obj_name": "", "reason": "collision", "estimates": 0, "candidates": 0,
                   "error": f"{type(exc).__name__}: {exc}"}
            _retreat(task)
        res.attempts += 1
        res.attempt_rows.append(row)
        ok = row["reason"] == "none"
        res.successes += ok
        res.removed += ok
        fails = 0 if ok else fails + 1
    res.reasons = {r: sum(a["reason"] == r for a in res.attempt_rows) for r in FAILURE_REASONS}
    res.wall_s = time.perf_counter() - t0
    return res


@dataclass
class DeclutterReport:
    """The rounds of a run and their pooled summary (GSR and DR with 95 % Wilson intervals)."""

    rounds: list[RoundResult]
    summary: dict

    def table(self) -> str:
        """The summary as Markdown."""
        return declutter_markdown(self.summary)


def summarize_rounds(rounds: Sequence[RoundResult]) -> dict:
    """Pooled GSR (successes / attempts) and DR (removed / objects) with 95 % Wilson intervals, per-round means,
    and the attempts' outcomes."""
    att = sum(r.attempts for r in rounds)
    ok = sum(r.successes for r in rounds)
    objs = sum(r.objects for r in rounds)
    rem = sum(r.removed for r in rounds)
    return {"rounds": len(rounds), "attempts": att, "successes": ok, "objects": objs, "removed": rem,
            "gsr": ok / att if att else 0.0, "gsr_ci95": list(wilson_interval(ok, att)),
            "dr": rem / objs if objs else 0.0, "dr_ci95": list(wilson_interval(rem, objs)),
            "mean_round_gsr": float(np.mean([r.gsr for r in rounds])) if rounds else 0.0,
            "mean_round_dr": float(np.mean([r.dr for r in rounds])) if rounds else 0.0,
            "by_reason": {k: sum(r.reasons.get(k, 0) for r in rounds) for k in FAILURE_REASONS},
            "median_round_s": float(np.median([r.wall_s for r in rounds])) if rounds else 0.0}


def declutter_markdown(s: dict) -> str:
    """:func:`summarize_rounds` (with ``config``) as Markdown."""
    cfg = s.get("config") or {}
    pct = lambda x: f"{100 * x:.1f}%"  # noqa: E731
    lines = ["# Clutter removal", "", f"Estimator `{cfg.get('estimator')}`, scene `{cfg.get('scene')}`, "
             f"{cfg.get('objects_per_scene')} objects per round, objects `{cfg.get('objects')}`, "
             f"seed {cfg.get('seed')}.",
             "", "| rounds | objects | removed | attempts | GSR | 95% CI | DR | 95% CI |",
             "|---:|---:|---:|---:|---:|---|---:|---|",
             f"| {s['rounds']} | {s['objects']} | {s['removed']} | {s['attempts']} | {pct(s['gsr'])} | "
             f"{pct(s['gsr_ci95'][0])} - {pct(s['gsr_ci95'][1])} | {pct(s['dr'])} | "
             f"{pct(s['dr_ci95'][0])} - {pct(s['dr_ci95'][1])} |", "", "| outcome | attempts |", "|---|---:|"]
    lines += [f"| {k} | {v} |" for k, v in s["by_reason"].items() if v]
    return "\n".join(lines) + "\n"


def _write_csv(path: Path, rows: list[dict], columns: list[str]) -> None:
    with path.open("w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=columns, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: ("" if isinstance(v, float) and not math.isfinite(v) else v) for k, v in r.items()})


def run_declutter(cfg: GraspRunConfig, out_dir: str | Path | None = None, *, progress: bool = True,
                  command_line: Sequence[str] | None = None, overwrite: bool = True) -> DeclutterReport:
    """``cfg.episodes`` rounds of ``cfg.scene`` with ``cfg.objects_per_scene`` objects (round ``i`` seeded as
    episode ``i``, :func:`~simtest.envs.runner.episode_seed`), in this process; writes ``rounds.csv``,
    ``attempts.csv``, ``summary.json`` and ``summary.md`` into ``out_dir``."""
    if cfg.scene not in SCENES:
        raise ConfigError(f"scene must be one of {', '.join(SCENES)}, got {cfg.scene!r}")
    if out_dir is not None:
        prepare_out_dir(out_dir, overwrite=overwrite)
    load_objects(cfg.objects, cfg.units, cfg.scale)
    task = DeclutterTask(width=cfg.width, height=cfg.height, episode={"objects": cfg.objects},
                         object_units=cfg.units, object_scale=cfg.scale)
    est = load_estimator(cfg.estimator, **cfg.estimator_options)
    planner = GraspPlanner(obstacles=cfg.planner_obstacles)
    rounds = []
    try:
        for i in range(cfg.episodes):
            r = run_round(task, est, planner, seed=episode_seed(cfg.seed, i), scene=cfg.scene,
                          n=cfg.objects_per_scene, objects=cfg.objects, index=i, timeout=cfg.timeout)
            rounds.append(r)
            if progress:
                print(f"round {i}: {r.removed}/{r.objects} removed in {r.attempts} attempts", file=sys.stderr)
    finally:
        task.close()
    summary = {**summarize_rounds(rounds), "config": {**cfg.to_dict(), "task": "declutter", "scene": cfg.scene,
                                                      "objects_per_scene": cfg.objects_per_scene},
               "command_line": list(command_line) if command_line is not None else None}
    if out_dir is not None:
        out = Path(out_dir)
        out.mkdir(parents=True, exist_ok=True)
        _write_csv(out / "rounds.csv", [{**dataclasses.asdict(r), "gsr": r.gsr, "dr": r.dr,
                                         "reasons": ";".join(f"{k}={v}" for k, v in r.reasons.items() if v)}
                                        for r in rounds],
                   ["round", "seed", "scene", "objects", "removed", "attempts", "successes", "gsr", "dr", "reasons",
                    "wall_s"])
        _write_csv(out / "attempts.csv", [{"round": r.round, **a} for r in rounds for a in r.attempt_rows],
                   ["round", "attempt", "obj_name", "reason", "estimates", "candidates", "error"])
        atomic_write_json(out / "summary.json", jsonable(summary))
        (out / "summary.md").write_text(declutter_markdown(summary), encoding="utf-8")
    return DeclutterReport(rounds, summary)
