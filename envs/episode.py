"""The scripted closed loop: observe -> estimate -> plan -> grasp -> lift -> hold, scored end to end.

:func:`run_episode` resets a :class:`~simtest.envs.task.GraspTask`, moves the arm to the observation
configuration (the wrist camera looking at the target from the robot's side), captures one RGB-D observation
(corrupted as the episode asks), runs the estimator, plans a grasp from the *estimated* pose
(:class:`~simtest.envs.planner.GraspPlanner`) and executes it on the task's physics: joint-space motion to
above the pre-grasp pose (clear of the object's estimated top), straight down to the pre-grasp pose, a slow
straight approach, closing, a straight lift by 0.15 m and a 1 s hold.

Success: the target is at least 0.10 m above its resting height and in the gripper (touching a finger) at
every control period of the 1.0 s hold, and held between both fingers at its end. Otherwise exactly one failure reason is recorded (:data:`FAILURE_REASONS`):

* ``estimator_error``: the estimator raised, called ``sys.exit``, returned something other than a list, or
  returned a malformed estimate for the target (not PoseEstimate-like, wrong shapes, not a rotation);
* ``estimator_timeout``: the estimator did not return within the time limit;
* ``no_estimate``: no estimate for the target, or one with NaN / inf values;
* ``no_feasible_grasp``: no grasp candidate passes the approach, table and collision checks;
* ``ik_failure``: candidates pass the geometric checks but IK reaches none (or a motion became unreachable);
* ``collision``: the arm pushed against the table or another object (contact force above
  :data:`COLLISION_FORCE`) on its way to the grasp, or touched the target before the straight approach
  (the approach itself is guarded: fingertips meeting the table stop it and the gripper closes there);
* ``missed``: after closing, the target does not touch both fingers;
* ``slipped``: grasped, but not at least 0.10 m up and held for the whole hold.

Pose errors of the estimate actually used (ADD(-S), re, re_sym, te, MSSD) are computed against the ground truth
at the moment of the observation; ``re_sym`` is the smallest rotation error over the object's symmetries, as in
``simtest eval``.

Nothing the estimator returns is dropped silently: estimates for the target that claim another
``target_index`` than 0 (an episode has one target) are ignored and noted in ``EpisodeResult.warnings``; the
reasons in the estimator's ``last_failures`` explain a missing estimate in ``EpisodeResult.error``.
"""

from __future__ import annotations

import logging

import time
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

import simtest  # noqa: F401
import mujoco

from simtest.envs.options import CONTROL_DT, HOLD_TIME, SUCCESS_HEIGHT
from simtest.envs.planner import GraspPlan, GraspPlanner, observed_obstacles
from simtest.envs.execution import (COLLISION_FORCE, GUARD_FORCE, Collision, PhaseMonitor,  # noqa: F401
                                    TableTouch, move_joints, to_pregrasp)
from simtest.envs.recording import EpisodeRecorder
from simtest.envs.reobserve import (FUSIONS, UPDATES, PoseFusion, ReobserveSpec, check_choice, parse_reobserve,
                                    plan_moved, waypoint)
from simtest.envs.task import GraspTask, as_task
from simtest.estimators.base import Observation, PoseEstimate, gt_access
from simtest.estimators.registry import load_estimator
from simtest.estimators.track_icp import TrackICPEstimator
from simtest.estimators.guard import DEFAULT_TIMEOUT_S, InvalidEstimate, call_estimator, check_estimate, log_fault
from simtest.geometry import Pose
from simtest.io.bop import mask_bbox
from simtest.metrics import pose as pose_metrics
from simtest.robot import (UnreachableError, approach, close_and_wait, gripper_width, lift_to, move_to,
                           set_gripper, tcp_pose)

log = logging.getLogger(__name__)

# The episode's internal names of the motion helpers (simtest.envs.execution, simtest.envs.recording).
_Collision, _TableTouch, _Monitor = Collision, TableTouch, PhaseMonitor
_move_joints, _to_pregrasp = move_joints, to_pregrasp
_Recorder = EpisodeRecorder

__all__ = ["EpisodeResult", "FAILURE_REASONS", "COLLISION_FORCE", "run_episode", "execute_grasp",
           "pose_errors", "pick_estimate"]

#: Every failure reason an episode can end with ("none" = success).
FAILURE_REASONS = ("none", "no_estimate", "no_feasible_grasp", "ik_failure", "missed", "slipped", "collision",
                   "estimator_error", "estimator_timeout")
_SYMMETRY_CACHE: dict[str, np.ndarray] = {}


@dataclass
class EpisodeResult:
    """Outcome of one closed-loop episode.

    Attributes:
        seed: The env seed of the episode.
        target_obj_id, target_name: The target object.
        success: Lifted >= 0.10 m and held >= 1.0 s.
        reason: ``"none"`` on success, else one of :data:`FAILURE_REASONS`.
        add_s: ADD(-S) of the estimate used, m (ADD-S for symmetric objects); NaN without an estimate.
        re_deg: Rotation error (geodesic), degrees; NaN without an estimate.
        re_sym_deg: Smallest rotation error over the object's symmetries (``simtest eval``'s ``re_sym``),
            degrees; equals ``re_deg`` for objects without symmetries; NaN without an estimate.
        te: Translation error, m; NaN without an estimate.
        mssd: Maximum symmetry-aware surface distance, m; NaN without an estimate.
        estimate_s: Wall time of the estimator call, s.
        wall_s: Wall time of the whole episode (reset included), s.
        sim_s: Simulated time, s.
        lift_height: Final height of the target above its resting height, m.
        occlusion: Requested occlusion level (``"L0".."L3"``).
        occluded_fraction: Measured occluded fraction of the target at the observation view (NaN at L0).
        visible_pixels: Target pixels visible in the observation.
        grasp_index: Index of the executed grasp candidate (-1 if none).
        approach_tilt_deg: Angle of the executed approach from straight down, degrees (NaN if none).
        error: What went wrong with the estimator (exception text, ``sys.exit``, the time limit, the invalid
            return value or estimate) for ``estimator_*`` and ``no_estimate`` outcomes; for collisions the
            phase, the two geoms and the contact force; for IK failures during execution the unreachable pose.
        traceback: The last frames of the estimator's traceback (``file:line in function: source > ...``) when
            it raised, exited or timed out.
        warnings: Estimates that were returned but not used, and why (``; ``-separated).
        planner_obstacles: Where the planner's collision check took the obstacles from: ``"sim"`` (the
            simulator's geometry) or ``"observed"`` (the observation's depth image).
        trace: The estimator's full traceback (not written to ``episodes.csv``; ``--fail-fast`` prints it).
        frames: Video frames (third-person | wrist), only when recording.
        stages: With re-observation, one record per look (``first``, ``approach k``, ``pregrasp``): its own
            pose errors and those of the pose used after it (:data:`simtest.envs.reobserve.STAGE_COLUMNS`);
            empty without (not in ``episodes.csv``).
    """

    seed: int | None
    target_obj_id: int
    target_name: str
    success: bool
    reason: str
    add_s: float = float("nan")
    re_deg: float = float("nan")
    re_sym_deg: float = float("nan")
    te: float = float("nan")
    mssd: float = float("nan")
    estimate_s: float = 0.0
    wall_s: float = 0.0
    sim_s: float = 0.0
    lift_height: float = 0.0
    occlusion: str = "L0"
    occluded_fraction: float = float("nan")
    visible_pixels: int = 0
    grasp_index: int = -1
    approach_tilt_deg: float = float("nan")
    error: str = ""
    traceback: str = ""
    warnings: str = ""
    planner_obstacles: str = "sim"
    trace: str = field(default="", repr=False)
    frames: list = field(default=None, repr=False)  # type: ignore[assignment]
    stages: list = field(default_factory=list, repr=False)

    def to_row(self) -> dict[str, Any]:
        """The scalar fields, for a CSV row."""
        row = asdict(self)
        row.pop("frames")
        row.pop("stages")
        return row


def execute_grasp(task: GraspTask, plan: GraspPlan, monitor: _Monitor | None = None, *, approach_speed: float = 0.08,
                  close_time: float = 0.6, hold: float = HOLD_TIME,
                  q_pregrasp: np.ndarray | None = None) -> str:
    """Execute a planned grasp on ``task``'s physics: pre-grasp, approach, close, lift, hold.

    The approach, closing and lift are the phases of the scripted grasp (:func:`simtest.robot.approach`,
    :func:`simtest.robot.close_and_wait`, :func:`simtest.robot.lift_to`); here a collision monitor watches
    them, the approach is guarded against the table and the hold is checked every control period.

    Args:
        task: The :class:`~simtest.envs.task.GraspTask` (or an env over one), its arm at rest.
        plan: From :meth:`GraspPlanner.plan`.
        monitor: Collision monitor / recorder (a fresh one if None).
        approach_speed: Mean TCP speed of the straight approach and lift, m/s.
        close_time: Time given to the gripper to close, s.
        hold: Hold time at the top, s.
        q_pregrasp: The arm's joint command (7,) rad when it already stands at ``plan``'s pre-grasp pose (after
            a re-observation there); None moves it there first.

    Returns:
        ``"none"`` on success, else ``"collision"``, ``"ik_failure"``, ``"missed"`` or ``"slipped"``.
    """
    task = as_task(task)
    m, d, ids = task.model, task.data, task.ids
    monitor = monitor or _Monitor(task, None)
    try:
        q = _to_pregrasp(task, plan, monitor) if q_pregrasp is None else q_pregrasp
        monitor.phase = "approach"
        dist = float(np.linalg.norm(plan.grasp.t - plan.pregrasp.t))
        try:
            q = approach(m, d, ids, plan.grasp, dist, approach_speed, q, settle=0.5, callback=monitor)
        except _TableTouch:  # guarded approach: stop where the fingertips met the table
            q = ids.arm_q(d)
            d.ctrl[ids.arm_actuators] = q
            task.advance(0.1)
        monitor.phase = "grasp"
        close_and_wait(m, d, ids, close_time, dt=CONTROL_DT, advance=task.advance, callback=monitor)
        if not task.is_grasped() or gripper_width(d, ids) < 0.002:
            return "missed"
        lift = float(np.linalg.norm(plan.lift.t - plan.grasp.t))
        lift_to(m, d, ids, plan.lift, lift, approach_speed, q, callback=monitor)
        mujoco.mj_kinematics(m, d)
        for _ in range(int(round(hold / CONTROL_DT))):
            if not (task.touches_gripper() and task.lift_height() >= SUCCESS_HEIGHT):
                return "slipped"
            task.advance(CONTROL_DT)
            monitor(m, d)
        if not (task.is_grasped() and task.lift_height() >= SUCCESS_HEIGHT):
            return "slipped"
        return "none"
    except _Collision as exc:
        monitor.note = str(exc)
        return "collision"
    except UnreachableError as exc:
        monitor.note = str(exc)
        return "ik_failure"
    finally:
        task.sync_command()


def pose_errors(obj, R_e: np.ndarray, t_e: np.ndarray, R_g: np.ndarray, t_g: np.ndarray) -> dict[str, float]:
    """ADD(-S) (m), re and re_sym (deg), te (m) and MSSD (m) of one estimate against the ground truth (camera
    frame)."""
    key = obj.mesh_hash
    if key not in _SYMMETRY_CACHE:
        _SYMMETRY_CACHE[key] = obj.symmetry_transforms()
    pts = np.asarray(obj.vertices)
    syms = _SYMMETRY_CACHE[key]
    pm = pose_metrics
    return {"add_s": pm.add_s_or_add(obj, R_e, t_e, R_g, t_g), "re_deg": pm.re(R_e, R_g),
            "re_sym_deg": pm.re_sym(R_e, R_g, syms), "te": pm.te(t_e, t_g),
            "mssd": pm.mssd(R_e, t_e, R_g, t_g, pts, syms)}


def pick_estimate(elements: list, obj_id: int, known: set[int]
                   ) -> tuple[PoseEstimate | None, InvalidEstimate | None, list[str]]:
    """The highest-scoring valid estimate of ``obj_id`` answering the first target (or no target); without one,
    the first invalid element for ``obj_id`` (or of unknown object) says why. The third item notes the
    estimates of ``obj_id`` that were valid but set another ``target_index`` (ignored)."""
    best, first_bad, notes = None, None, []
    for i, element in enumerate(elements):
        e, why = check_estimate(element, known, index=i)
        if why is not None:
            if first_bad is None and why.obj_id in (None, obj_id):
                first_bad = why
        elif e.obj_id == obj_id and e.target_index not in (None, 0):
            notes.append(f"estimate [{i}] of obj_id {obj_id} has target_index {e.target_index!r}, but the episode "
                         "has one target (index 0, or None): ignored")
        elif e.obj_id == obj_id and (best is None or e.score > best.score):
            best = e
    return best, (None if best is not None else first_bad), notes


def _no_estimate_reason(est: Any, obj_id: int, notes: list[str]) -> str:
    """Why there is no estimate: the estimator's own ``last_failures`` for ``obj_id``, else the ignored
    estimates, else ``""``."""
    reasons = [str(f.get("reason", "")) for f in list(getattr(est, "last_failures", None) or [])
               if isinstance(f, dict) and f.get("obj_id") in (None, obj_id)]
    return "; ".join(r for r in reasons if r) or "; ".join(notes)


def orthonormal(R: np.ndarray) -> np.ndarray:
    """The rotation nearest to ``R`` (a checked rotation, within rounding)."""
    U, _, Vt = np.linalg.svd(R)
    return U @ Vt


def _observation(u: GraspTask, est: Any, obs: dict, seed: int | None, im_id: int, prior: tuple | None = None
                 ) -> tuple[Observation, np.ndarray, np.ndarray, np.ndarray]:
    """The estimator's :class:`Observation` of the capture ``obs`` (look ``im_id`` of the episode), the target's
    visible mask and its ground-truth ``(R, t)`` in the camera frame at the capture. With ``prior`` (a ``(R, t)``
    in this camera frame) the observation starts a track there (``track_ids``, ``init_poses``)."""
    info = u.current_info()
    mask = u.target_mask()
    tid = int(u.target_obj.obj_id)
    T_cam_obj_gt = info["T_cam_obj"][u.grasp_scene.target_instance]
    R_g, t_g = T_cam_obj_gt[:3, :3], T_cam_obj_gt[:3, 3]
    box = tuple(mask_bbox(mask)) if mask.any() else (0, 0, 0, 0)  # BOP's bbox_visib convention
    gt_masks, needs_gt = gt_access(est)
    observation = Observation(
        rgb=obs["rgb"], depth=obs["depth"], K=obs["K"], width=u.width, height=u.height, objects=u.objects,
        target_obj_ids=(tid,), masks=(mask,) if gt_masks else None, boxes=(box,) if gt_masks else None,
        gt_poses=((R_g.copy(), t_g.copy()),) if needs_gt else None,
        scene_id=int(seed) if seed is not None else 0, im_id=im_id,
        **({} if prior is None else {"frame_index": 0, "track_ids": (0,), "init_poses": (prior,)}))
    return observation, mask, R_g, t_g


def _T_world_cam(u: GraspTask, obs: dict) -> Pose:
    """``T_world_cam`` of the capture ``obs`` (m)."""
    return Pose.from_matrix(u.current_info()["T_world_base"]) @ Pose.from_matrix(obs["T_base_cam"])


def run_episode(task: GraspTask, estimator, planner: GraspPlanner | None = None, seed: int | None = None,
                options: dict | None = None, *, record: bool = False, record_every: int = 2,
                timeout: float | None = DEFAULT_TIMEOUT_S, reobserve: str | ReobserveSpec = "none",
                reobserve_update: str = "estimate", reobserve_fusion: str = "mean") -> EpisodeResult:
    """Run one closed-loop episode (see the module docstring).

    Args:
        task: The :class:`~simtest.envs.task.GraspTask`, or a :class:`~simtest.envs.grasp_env.PandaGraspEnv`
            over one (wrappers are looked through; the episode drives the task, past ``step``).
        estimator: An estimator instance, a callable, a registered name or ``module:attr``. Estimators with a
            true ``needs_gt`` attribute (the ``oracle``) get the ground-truth pose in
            ``Observation.gt_poses``; those with ``needs_gt_masks`` (or ``needs_gt``) the target's
            ground-truth visible mask and box (the "GT detections" protocol); every estimator gets the
            target's object id, no other ground truth.
        planner: The grasp planner (default :class:`GraspPlanner`). With ``obstacles="observed"`` it gets the
            obstacles the observation's depth image shows (:func:`~simtest.envs.planner.observed_obstacles`,
            the target removed at its estimated pose).
        seed: Env seed of the episode (scene, corruption and, through ``Observation.scene_id``, oracle noise).
        options: ``reset`` options (objects, target, n_distractors, occlusion, corruption, depth_noise, ...).
        record: Keep video frames (third-person | wrist) in ``EpisodeResult.frames``.
        record_every: Record every n-th control period (2 -> 10 frames per simulated second).
        timeout: Time limit of the estimator call, seconds (``None`` or 0: none); over it the episode ends
            as ``estimator_timeout``.
        reobserve: Looks on the way in (:func:`~simtest.envs.reobserve.parse_reobserve`): ``"none"``,
            ``"pregrasp"`` or ``"approach:K"``; every look's pose errors go to ``EpisodeResult.stages``.
        reobserve_update, reobserve_fusion: How a look updates the pose
            (:data:`~simtest.envs.reobserve.UPDATES`, :data:`~simtest.envs.reobserve.FUSIONS`).

    Returns:
        An :class:`EpisodeResult`; estimator failures (exceptions, ``sys.exit``, timeouts, invalid return
        values) are recorded, never raised. ``KeyboardInterrupt`` propagates. With re-observation, the pose
        errors of the result are those of the pose the grasp was finally planned from.
    """
    t_start = time.perf_counter()
    spec = parse_reobserve(reobserve)
    check_choice("reobserve_update", reobserve_update, UPDATES)
    check_choice("reobserve_fusion", reobserve_fusion, FUSIONS)
    u = as_task(task)
    est = load_estimator(estimator)
    planner = planner or GraspPlanner()
    u.reset(seed=seed, options=options)
    obj = u.target_obj
    tid = int(obj.obj_id)
    t_sim0 = float(u.data.time)
    occ = u.occlusion
    result = EpisodeResult(seed=seed, target_obj_id=tid, target_name=obj.name, success=False, reason="none",
                           occlusion=f"L{u.config.occlusion}", planner_obstacles=planner.obstacles,
                           occluded_fraction=float("nan") if occ is None or occ.occluded_fraction is None
                           else occ.occluded_fraction)
    recorder = _Recorder(u, record_every) if record else None
    monitor = _Monitor(u, recorder)

    def finish(reason: str) -> EpisodeResult:
        u.sync_command()
        result.reason = reason
        result.success = reason == "none"
        result.lift_height = u.lift_height()
        result.sim_s = float(u.data.time) - t_sim0
        result.wall_s = time.perf_counter() - t_start
        if recorder is not None:
            recorder(force=True)
            result.frames = recorder.frames
        return result

    # 1. Observe from the observation configuration.
    try:
        _move_joints(u, u.q_observe, monitor)
    except _Collision as exc:
        result.error = str(exc)
        return finish("collision")
    obs = u.capture()
    observation, mask, R_g, t_g = _observation(u, est, obs, seed, 0)
    result.visible_pixels = int(mask.sum())

    # 2. Estimate.
    t0 = time.perf_counter()
    elements, fault = call_estimator(est, observation, timeout)
    result.estimate_s = time.perf_counter() - t0
    if fault is not None:
        result.error, result.traceback, result.trace = fault.message, fault.trace_tail, fault.trace
        log_fault(log, f"episode seed {seed}", fault, "episodes.csv")
        return finish("estimator_timeout" if fault.kind == "timeout" else "estimator_error")
    chosen, why, notes = pick_estimate(elements, tid, set(u.objects.ids))
    result.warnings = "; ".join(notes)
    if chosen is None:
        result.error = why.message if why is not None else _no_estimate_reason(est, tid, notes)
        return finish("estimator_error" if why is not None and why.problem != "non-finite" else "no_estimate")
    R_e, t_e = orthonormal(chosen.R), chosen.t
    errs = pose_errors(obj, R_e, t_e, R_g, t_g)
    result.add_s, result.re_deg, result.re_sym_deg, result.te, result.mssd = (
        errs["add_s"], errs["re_deg"], errs["re_sym_deg"], errs["te"], errs["mssd"])

    # 3. Plan from the estimated pose, camera -> base -> world.
    T_world_obj = _T_world_cam(u, obs) @ Pose(R_e, t_e)
    if recorder is not None:
        recorder.T_world_obj_est = T_world_obj.matrix()
    points = (observed_obstacles(u, obs, obj, T_world_obj) if planner.obstacles == "observed" else None)
    planned = planner.plan(u, obj, T_world_obj, obstacle_points=points)
    if planned.plan is None:
        result.error = planned.explain()
        return finish(planned.reason)
    result.grasp_index = planned.plan.index
    result.approach_tilt_deg = float(np.degrees(planned.plan.approach_tilt))

    # 4. Execute, looking again on the way in when asked.
    plan, q_pre = planned.plan, None
    if spec.active:
        looks = _Looks(u, est, planner, obj, PoseFusion(T_world_obj, _symmetries(obj), reobserve_fusion),
                       reobserve_update, seed, timeout, recorder, result)
        try:
            plan, q_pre = looks.run(spec, plan, monitor, errs)
        except (_Collision, UnreachableError) as exc:
            result.error = str(exc)
            return finish("collision" if isinstance(exc, _Collision) else "ik_failure")
    reason = execute_grasp(u, plan, monitor, q_pregrasp=q_pre)
    result.error = monitor.note
    return finish(reason)


def _symmetries(obj) -> np.ndarray:
    key = obj.mesh_hash
    if key not in _SYMMETRY_CACHE:
        _SYMMETRY_CACHE[key] = obj.symmetry_transforms()
    return _SYMMETRY_CACHE[key]


def _stage_row(stage: str, found: bool, look: dict | None, used: dict, replanned: bool, visible: int,
               estimate_s: float) -> dict:
    """One look's record (:data:`~simtest.envs.reobserve.STAGE_COLUMNS` less the episode's own columns)."""
    nan = float("nan")
    return {"stage": stage, "found": found, "add_s": look["add_s"] if look else nan,
            "re_sym_deg": look["re_sym_deg"] if look else nan, "te": look["te"] if look else nan,
            "used_add_s": used["add_s"], "used_re_sym_deg": used["re_sym_deg"], "used_te": used["te"],
            "replanned": replanned, "visible_pixels": int(visible), "estimate_s": float(estimate_s)}


class _Looks:
    """The re-observations of one episode (:mod:`simtest.envs.reobserve`): move, capture, update the pose,
    re-plan; the stage records go to ``result.stages``."""

    def __init__(self, u: GraspTask, est: Any, planner: GraspPlanner, obj, fusion: PoseFusion, update: str,
                 seed: int | None, timeout: float | None, recorder: _Recorder | None, result: EpisodeResult) -> None:
        self.u, self.est, self.planner, self.obj, self.fusion = u, est, planner, obj, fusion
        self.update, self.seed, self.timeout, self.recorder, self.result = update, seed, timeout, recorder, result
        self.tracker = None
        if update == "track" and not callable(getattr(est, "track", None)):
            self.tracker = TrackICPEstimator()
        self.used_errors: dict = {}

    def run(self, spec: ReobserveSpec, plan: GraspPlan, monitor: _Monitor, first: dict
            ) -> tuple[GraspPlan, np.ndarray]:
        """Look at every stage of ``spec`` on the way to ``plan``'s pre-grasp pose (``first``: the first look's
        pose errors); returns the plan to execute and the joint command (7,) rad at its pre-grasp pose (the arm
        stands there). The result's pose errors and grasp become those of the final pose and plan."""
        res = self.result
        res.stages = [_stage_row("first", True, first, first, False, res.visible_pixels, res.estimate_s)]
        try:
            plan, q = self._stages(spec, plan, monitor)
        finally:  # a collision on the way still reports the errors of the pose the arm was moving by
            errs = self.used_errors or first
            if errs:
                res.add_s, res.re_deg, res.re_sym_deg, res.te, res.mssd = (
                    errs["add_s"], errs["re_deg"], errs["re_sym_deg"], errs["te"], errs["mssd"])
        res.grasp_index = plan.index
        res.approach_tilt_deg = float(np.degrees(plan.approach_tilt))
        return plan, q

    def _stages(self, spec: ReobserveSpec, plan: GraspPlan, monitor: _Monitor) -> tuple[GraspPlan, np.ndarray]:
        u = self.u
        d, ids = u.data, u.ids
        start = tcp_pose(d, ids)
        q = d.ctrl[ids.arm_actuators].copy()
        at_pre = False
        for k, (name, frac) in enumerate(spec.stages(), start=1):
            if frac < 1.0:
                monitor.phase = "free"
                set_gripper(d, ids, plan.open_width)
                goal = waypoint(start, plan.above, frac)
                dist = float(np.linalg.norm(goal.t - tcp_pose(d, ids).t))
                q = move_to(u.model, d, ids, goal, max(0.5, dist / 0.2), q_ref=q, settle=0.3, callback=monitor)
            else:
                q = _to_pregrasp(u, plan, monitor)
                at_pre = True
            new = self._look(name, k, plan)
            if new is not None and plan_moved(plan, new):
                plan, at_pre = new, False
                self.result.stages[-1]["replanned"] = True
        if not at_pre:
            q = _to_pregrasp(u, plan, monitor)
        return plan, q

    def _estimate(self, obs: dict, k: int) -> tuple[list, Any, np.ndarray, np.ndarray, np.ndarray, float]:
        u, est = self.u, self.est
        T_cam_world = _T_world_cam(u, obs).inverse()
        prior = None
        if self.update == "track":
            P = T_cam_world @ self.fusion.pose
            prior = (P.R.copy(), P.t.copy())
        observation, mask, R_g, t_g = _observation(u, est, obs, self.seed, k, prior)
        t0 = time.perf_counter()
        if self.update == "track" and self.tracker is None:
            elements, fault = call_estimator(lambda o: est.track(o, prior), observation, self.timeout)
        else:
            elements, fault = call_estimator(self.tracker or est, observation, self.timeout)
        return elements, fault, mask, R_g, t_g, time.perf_counter() - t0

    def _look(self, name: str, k: int, plan: GraspPlan) -> GraspPlan | None:
        """Capture look ``k``, update the pose, re-plan; the new plan (None: none feasible or no estimate)."""
        u, obj, res = self.u, self.obj, self.result
        obs = u.capture()
        elements, fault, mask, R_g, t_g, dt = self._estimate(obs, k)
        T_world_cam = _T_world_cam(u, obs)
        chosen = None
        if fault is None:
            chosen, _, notes = pick_estimate(elements, int(obj.obj_id), set(u.objects.ids))
        else:
            notes = [f"{name}: {fault.message}"]
        look = None
        if chosen is not None:
            R_e, t_e = orthonormal(chosen.R), chosen.t
            look = pose_errors(obj, R_e, t_e, R_g, t_g)
            self.fusion.add(T_world_cam @ Pose(R_e, t_e))
        elif notes:
            res.warnings = "; ".join(x for x in (res.warnings, f"{name}: no estimate ({'; '.join(notes)})") if x)
        used = T_world_cam.inverse() @ self.fusion.pose
        self.used_errors = pose_errors(obj, used.R, used.t, R_g, t_g)
        res.stages.append(_stage_row(name, chosen is not None, look, self.used_errors, False, int(mask.sum()), dt))
        if chosen is None:
            return None
        if self.recorder is not None:
            self.recorder.T_world_obj_est = self.fusion.pose.matrix()
        points = (observed_obstacles(u, obs, obj, self.fusion.pose) if self.planner.obstacles == "observed"
                  else None)
        return self.planner.plan(u, obj, self.fusion.pose, obstacle_points=points).plan
