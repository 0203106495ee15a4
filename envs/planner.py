"""Grasp planning from an *estimated* object pose.

The object's grasp candidates (:attr:`simtest.objects.ObjectModel.grasps`, ``T_obj_grasp`` in the gripper
convention of :mod:`simtest.robot`: origin at the TCP, z = approach, y = closing axis) are mapped into the
world through the estimated pose ``T_world_obj = T_world_base @ T_base_cam @ T_cam_obj``. A candidate is
kept when

1. its approach points downward: at most ``max_tilt`` from straight down (a gripper coming from below the
   horizon would have to pass through the table);
2. the open gripper (both fingers at the full 0.08 m opening and the palm, as boxes) stays at least
   ``table_clearance`` above the table top at the grasp pose (the pre-grasp pose is higher still); a
   candidate that would reach into the table is backed off along its approach axis while its contacts stay
   on the finger pads (flat objects are held near the fingertips);
3. IK reaches the pre-grasp, grasp and lift poses (within 0.5 mm / 0.3 deg);
4. with ``check_collisions``, the arm at the pre-grasp and grasp configurations (gripper open) does not
   penetrate the table, the distractors or the occluders. The target itself is known only through its
   estimate (the candidates already keep the fingers out of its estimated surface). Where the obstacles come
   from is the planner's ``obstacles`` setting (:data:`OBSTACLE_SOURCES`):

   * ``"sim"``: the simulator's geometry (its contacts), as a perfect occupancy map would give them;
   * ``"observed"``: only what the camera saw, :func:`observed_obstacles`: the observation's depth image
     back-projected into the world, minus the points within ``target_margin`` of the target's surface at its
     *estimated* pose, minus the table top (and below) and the robot's own geoms at the capture
     configuration. The hand and fingers at a configuration (their collision geoms' boxes, grown by
     ``obstacle_margin``) must contain none of these points. The table is known workspace: the arm's
     contacts with it are still checked on the simulator's geometry, nothing else is.

Candidates are ranked by ``top_down_weight * (-approach_z) + score - shift_weight * contact_shift / 12 mm``
(top-down grasps preferred, then the sampler's antipodal quality, then contacts on the middle of the pads
rather than near the fingertips) and checked in that order; for each, the grasp and its twin rotated by pi
about the approach axis (:func:`simtest.robot.symmetric_grasp`) are tried and the one needing the smaller
joint motion is taken. The first feasible candidate wins.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

import simtest  # noqa: F401
import mujoco

from scipy.spatial import cKDTree

from simtest.camera import backproject
from simtest.envs.task import GraspTask, as_task
from simtest.robot import GRIPPER_OPEN, solve_ik, symmetric_grasp
from simtest.errors import ConfigError
from simtest.geometry import Pose
from simtest.objects.grasps import PANDA, gripper_boxes

__all__ = ["GraspPlan", "PlanResult", "REJECTION_CAUSES", "GraspPlanner", "OBSTACLE_SOURCES", "observed_obstacles",
           "points_in_geoms"]

#: Where the planner's collision check takes the obstacles from (see the module docstring).
OBSTACLE_SOURCES = ("sim", "observed")


@dataclass(frozen=True)
class GraspPlan:
    """A feasible grasp, ready to execute.

    Attributes:
        grasp: ``T_world_tcp`` at the grasp (m).
        pregrasp: ``T_world_tcp`` ``pregrasp`` metres back along the approach axis.
        above: The pre-grasp pose raised, if needed, until the open gripper is ``clearance`` above the
            object's estimated top:
            reached first (joint-space motion), then the pre-grasp straight down from it, so a tilted
            approach does not swing the fingers through the object.
        q_above: IK solution of ``above`` (7,), rad.
        lift: ``T_world_tcp`` after lifting straight up.
        q_pregrasp, q_grasp, q_lift: IK solutions (7,), rad.
        width: Contact width of the candidate, m.
        open_width: Gripper opening for the approach, m: ``width + open_margin``, at most 0.08. Opening
            wider than the grasp needs would, in a rim grasp, put the inner finger onto the opposite wall.
        index: Index of the candidate in the object's grasp set.
        flipped: Whether the twin rotated by pi about the approach axis was taken.
        approach_tilt: Angle between the approach axis and straight down, rad.
        score: The candidate's grasp quality in [0, 1].
    """

    grasp: Pose
    pregrasp: Pose
    lift: Pose
    above: Pose
    q_above: np.ndarray
    q_pregrasp: np.ndarray
    q_grasp: np.ndarray
    q_lift: np.ndarray
    width: float
    open_width: float
    index: int
    flipped: bool
    approach_tilt: float
    score: float


@dataclass(frozen=True)
class PlanResult:
    """Outcome of :meth:`GraspPlanner.plan` (:meth:`explain` says it in words).

    Attributes:
        plan: The chosen grasp, or ``None``.
        reason: ``"ok"``, ``"no_feasible_grasp"`` (no candidate passes the approach and table checks, or all
            that reach collide) or ``"ik_failure"`` (candidates pass the geometric checks but IK reaches none).
        n_candidates: Candidates of the object.
        n_geometric: Candidates passing the approach-direction and table checks.
        n_tried: Candidates whose IK was tried.
        rejected: Candidates rejected, by cause (:data:`REJECTION_CAUSES`: approach tilted too far, table
            clearance, unreachable, in collision, not tried beyond ``max_candidates``); without a plan the
            counts add up to ``n_candidates``.
    """

    plan: GraspPlan | None
    reason: str
    n_candidates: int
    n_geometric: int
    n_tried: int
    rejected: dict = field(default_factory=dict)

    def explain(self) -> str:
        """The outcome in words, e.g. ``"no_feasible_grasp: 12 candidates, 9 rejected for table clearance, 3
        unreachable"`` (``"ok"`` for a plan)."""
        if self.plan is not None:
            return "ok"
        parts = [f"{self.n_candidates} candidates"]
        parts += [f"{k} {REJECTION_CAUSES[cause]}" for cause, k in self.rejected.items() if k]
        return f"{self.reason}: " + ", ".join(parts)


#: Causes a grasp candidate is rejected for (:attr:`PlanResult.rejected`), with their words.
REJECTION_CAUSES = {"approach": "rejected for an approach tilted beyond max_tilt",
                    "table": "rejected for table clearance",
                    "unreachable": "unreachable",
                    "collision": "in collision",
                    "untried": "not tried (beyond max_candidates)"}


def _box_corners(boxes: np.ndarray) -> np.ndarray:
    """(B, 2, 3) [lo, hi] boxes -> (B * 8, 3) corners."""
    lo, hi = boxes[:, 0], boxes[:, 1]
    out = []
    for sx in (0, 1):
        for sy in (0, 1):
            for sz in (0, 1):
                out.append(np.stack([np.where(sx, hi[:, 0], lo[:, 0]), np.where(sy, hi[:, 1], lo[:, 1]),
                                     np.where(sz, hi[:, 2], lo[:, 2])], axis=1))
    return np.concatenate(out, axis=0)


def points_in_geoms(model: mujoco.MjModel, data: mujoco.MjData, geoms: np.ndarray, points: np.ndarray,
                    margin: float = 0.0) -> np.ndarray:
    """Which points (N, 3), world frame, m, lie inside any of ``geoms``' bounding boxes grown by ``margin`` (m).

    Each geom's box is its local axis-aligned bounding box (``model.geom_aabb``) at its world pose in ``data``
    (after forward kinematics), so boxes follow the geoms' orientation.

    Returns:
        (N,) bool.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    inside = np.zeros(len(pts), dtype=bool)
    for g in np.asarray(geoms, dtype=int):
        centre, half = model.geom_aabb[g, :3], model.geom_aabb[g, 3:] + margin
        R = data.geom_xmat[g].reshape(3, 3)
        local = (pts - data.geom_xpos[g]) @ R - centre
        inside |= (np.abs(local) <= half).all(axis=1)
    return inside


def _voxel_downsample(points: np.ndarray, voxel: float) -> np.ndarray:
    """One point (the first) per ``voxel``-sized cube (m)."""
    if len(points) == 0 or voxel <= 0:
        return points
    keys = np.floor(points / voxel).astype(np.int64)
    _, first = np.unique(keys, axis=0, return_index=True)
    return points[np.sort(first)]


def observed_obstacles(task: GraspTask, obs: dict, obj, T_world_obj: Pose, *, target_margin: float = 0.01,
                       table_margin: float = 0.005, self_margin: float = 0.01,
                       voxel: float = 0.004) -> np.ndarray:
    """The obstacles the camera saw: world points (M, 3), metres, from an observation's depth image.

    The depth image (planar, metres, 0 = missing) is back-projected with ``obs["K"]`` and moved into the world
    with the camera pose the observation carries (``T_world_base @ obs["T_base_cam"]``, OpenCV frame). Removed:

    * points within ``target_margin`` of the target's surface (:meth:`ObjectModel.surface_cloud`) at its
      *estimated* pose ``T_world_obj`` (the target is what the gripper must touch);
    * points less than ``table_margin`` above the known table top ``task.grasp_scene.table_height``, or below it
      (the table is known workspace, checked separately);
    * points inside the robot's own collision geoms (grown by ``self_margin``) at the arm's current
      configuration, which must be the one of the capture (the robot knows its own joints);

    and the rest is thinned to one point per ``voxel`` cube.

    Args:
        task: The :class:`~simtest.envs.task.GraspTask` in the state of the capture (or an env over one).
        obs: The observation (``depth``, ``K``, ``T_base_cam``).
        obj: The target's :class:`simtest.objects.ObjectModel`.
        T_world_obj: The target's estimated pose in the world (m).
    """
    task = as_task(task)
    T_world_cam = task.T_world_base @ Pose.from_matrix(np.asarray(obs["T_base_cam"], dtype=np.float64))
    pts = T_world_cam.apply(backproject(obs["depth"], np.asarray(obs["K"], dtype=np.float64)))  # depth > 0 only
    pts = pts[pts[:, 2] > task.grasp_scene.table_height + table_margin]
    surface = T_world_obj.apply(obj.surface_cloud(4000)[0])
    dist, _ = cKDTree(surface).query(pts, distance_upper_bound=target_margin)
    pts = pts[~np.isfinite(dist)]
    mujoco.mj_kinematics(task.model, task.data)
    pts = pts[~points_in_geoms(task.model, task.data, task.ids.robot_geoms, pts, self_margin)]
    return _voxel_downsample(pts, voxel)


def _hand_geoms(model: mujoco.MjModel, ids) -> np.ndarray:
    """Collision geoms of the hand and fingers: the robot's geoms on the hand body and its descendants."""
    def under_hand(body: int) -> bool:
        while body > 0:
            if body == ids.hand_body:
                return True
            body = int(model.body_parentid[body])
        return False

    return np.array([g for g in ids.robot_geoms if under_hand(int(model.geom_bodyid[g]))], dtype=int)


def _table_geoms(model: mujoco.MjModel) -> np.ndarray:
    """Geoms of the table (named ``table*``)."""
    return np.array([g for g in range(model.ngeom)
                     if (mujoco.mj_id2name(model, mujoco.mjtObj.mjOBJ_GEOM, g) or "").startswith("table")], dtype=int)


@dataclass(frozen=True)
class _Obstacles:
    """Observed obstacles of one planning call: the points (world, m) and the geoms to test them against."""

    points: np.ndarray
    hand_geoms: np.ndarray
    table_geoms: np.ndarray


class GraspPlanner:
    """Chooses a feasible grasp of an object from its estimated pose (see the module docstring).

    Args:
        max_tilt: Largest angle between the approach axis and straight down, rad.
        table_clearance: Smallest height of the open gripper above the table top, m.
        pregrasp: Stand-off along the approach axis before the straight approach, m.
        lift: Lift height (TCP straight up), m.
        top_down_weight: Weight of ``-approach_z`` against the candidate score in the ranking.
        max_candidates: Candidates tried with IK before giving up.
        check_collisions: Reject candidates whose pre-grasp or grasp configuration penetrates obstacles.
        max_contact_z: How far beyond the TCP (toward the fingertips, which are 0.022 m beyond it) the
            contacts may end up when a candidate is backed off to clear the table, m.
        shift_weight: Ranking penalty per 12 mm the contacts sit beyond the TCP (toward the fingertips):
            grasps held on the middle of the pads hold better than rim grasps on their tips.
        clearance: Height of the open gripper's lowest point above the object's estimated top before it
            descends to a pre-grasp pose that is lower than that, m.
        open_margin: Opening beyond the contact width for the approach (both fingers together), m.
        obstacles: Obstacle source of the collision check, one of :data:`OBSTACLE_SOURCES`: ``"sim"`` (the
            simulator's geometry) or ``"observed"`` (the observed point cloud passed to :meth:`plan`).
        obstacle_margin: With ``"observed"``: how far the hand's and fingers' boxes are grown, m.
    """

    def __init__(self, max_tilt: float = np.deg2rad(60.0), table_clearance: float = 0.002,
                 pregrasp: float = 0.10, lift: float = 0.15, top_down_weight: float = 2.0,
                 max_candidates: int = 30, check_collisions: bool = True, max_contact_z: float = 0.020,
                 shift_weight: float = 0.3, clearance: float = 0.03, open_margin: float = 0.05,
                 obstacles: str = "sim", obstacle_margin: float = 0.005) -> None:
        if not 0 < max_tilt <= np.pi / 2:
            raise ConfigError(f"max_tilt must be in (0, pi/2] rad, got {max_tilt!r}")
        if not pregrasp > 0 or not lift > 0:
            raise ConfigError(f"pregrasp and lift must be > 0 m, got {pregrasp!r} and {lift!r}")
        if max_candidates < 1:
            raise ConfigError(f"max_candidates must be >= 1, got {max_candidates!r}")
        if obstacles not in OBSTACLE_SOURCES:
            raise ConfigError(f"planner obstacles must be one of {', '.join(OBSTACLE_SOURCES)}; got {obstacles!r}")
        if not obstacle_margin >= 0:
            raise ConfigError(f"obstacle_margin must be >= 0 m, got {obstacle_margin!r}")
        self.obstacles = obstacles
        self.obstacle_margin = float(obstacle_margin)
        self.max_tilt = float(max_tilt)
        self.table_clearance = float(table_clearance)
        self.pregrasp = float(pregrasp)
        self.lift = float(lift)
        self.top_down_weight = float(top_down_weight)
        self.max_candidates = int(max_candidates)
        self.check_collisions = bool(check_collisions)
        self.max_contact_z = float(max_contact_z)
        self.shift_weight = float(shift_weight)
        self.clearance = float(clearance)
        self.open_margin = float(open_margin)
        self._open_corners = _box_corners(gripper_boxes(PANDA.max_width, PANDA))

    def candidates_world(self, obj, T_world_obj: Pose) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """All candidates in the world: ``(poses (N, 4, 4), widths (N,), scores (N,), contact_z (N,))``.

        ``contact_z`` is how far the contacts sit beyond the TCP along the approach axis (m; 0 for most
        candidates, up to 0.012 for rim grasps).
        """
        gs = obj.grasps
        poses = np.asarray(gs.poses)
        contacts = np.asarray(gs.contacts)
        if len(poses):
            rel = contacts.mean(axis=1) - poses[:, :3, 3]
            contact_z = np.einsum("ni,ni->n", rel, poses[:, :3, 2])
            contact_z = np.where(np.isfinite(contact_z), contact_z, 0.0)
        else:
            contact_z = np.zeros(0)
        return (T_world_obj.matrix()[None] @ poses, np.asarray(gs.widths), np.asarray(gs.scores), contact_z)

    def geometric_filter(self, poses: np.ndarray, table_height: float,
                         contact_z: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
        """Approach-direction and table-clearance checks.

        A candidate whose open fingers would reach into the table is backed off along its approach axis
        until they clear it, as long as the contacts stay on the pads (at most ``max_contact_z`` beyond the
        TCP): flat objects are then held by the fingertip ends of the pads.

        Returns:
            ``(ok (N,) bool, backoff (N,) m)``: which candidates pass, and how far each must back off.
        """
        n = len(poses)
        if n == 0:
            return np.zeros(0, bool), np.zeros(0)
        contact_z = np.zeros(n) if contact_z is None else np.asarray(contact_z)
        az = poses[:, 2, 2]  # world z of the approach axis
        ok = az <= -np.cos(self.max_tilt)
        corners = np.einsum("nij,kj->nki", poses[:, :3, :3], self._open_corners) + poses[:, None, :3, 3]
        deficit = table_height + self.table_clearance - corners[:, :, 2].min(axis=1)
        with np.errstate(divide="ignore", invalid="ignore"):
            backoff = np.where(deficit > 0, deficit / np.maximum(-az, 1e-6), 0.0)
        ok &= contact_z + backoff <= self.max_contact_z
        return ok, np.where(ok, backoff, 0.0)

    def plan(self, task: GraspTask, obj, T_world_obj: Pose, obstacle_points: np.ndarray | None = None
             ) -> PlanResult:
        """Choose a grasp for ``obj`` at the estimated ``T_world_obj`` in ``task``'s current state.

        Args:
            task: A reset :class:`~simtest.envs.task.GraspTask` (its model, data and Panda ids are read, never
                stepped), or a :class:`~simtest.envs.grasp_env.PandaGraspEnv` over one (wrapped or not).
            obj: The target's :class:`simtest.objects.ObjectModel`.
            T_world_obj: The *estimated* object pose in the world (m).
            obstacle_points: With ``obstacles="observed"`` (required then): the observed obstacles, (M, 3)
                world points, m (:func:`observed_obstacles`); ignored with ``"sim"``.

        Raises:
            ConfigError: ``obstacles="observed"`` without ``obstacle_points``.
        """
        task = as_task(task)
        model, data, ids = task.model, task.data, task.ids
        observed = None
        if self.obstacles == "observed":
            if obstacle_points is None:
                raise ConfigError("GraspPlanner(obstacles='observed').plan needs obstacle_points (the observed "
                                  "obstacle cloud, see observed_obstacles)")
            observed = _Obstacles(np.asarray(obstacle_points, dtype=np.float64).reshape(-1, 3),
                                  _hand_geoms(model, ids), _table_geoms(model))
        poses, widths, scores, contact_z = self.candidates_world(obj, T_world_obj)
        n = len(poses)
        ok, backoff = self.geometric_filter(poses, task.grasp_scene.table_height, contact_z)
        steep = poses[:, 2, 2] > -np.cos(self.max_tilt) if n else np.zeros(0, bool)
        rejected = {"approach": int(steep.sum()), "table": int((~ok & ~steep).sum()), "unreachable": 0,
                    "collision": 0, "untried": 0}
        poses = poses.copy()
        poses[:, :3, 3] -= backoff[:, None] * poses[:, :3, 2]
        idx = np.flatnonzero(ok)
        if len(idx) == 0:
            return PlanResult(None, "no_feasible_grasp", n, 0, 0, rejected)
        rank = (self.top_down_weight * (-poses[idx, 2, 2]) + scores[idx]
                - self.shift_weight * (contact_z[idx] + backoff[idx]) / 0.012)
        order = idx[np.argsort(-rank, kind="stable")]
        q_now = ids.arm_q(data)
        top_z = float((np.asarray(obj.vertices) @ T_world_obj.R.T + T_world_obj.t)[:, 2].max())
        n_tried = 0
        any_ik = False
        rejected["untried"] = int(max(0, len(order) - self.max_candidates))
        for i in order[: self.max_candidates]:
            n_tried += 1
            best = None
            hit = False
            for flipped in (False, True):
                g = Pose.from_matrix(poses[i])
                if flipped:
                    g = symmetric_grasp(g)
                res = self._check(model, data, ids, task, g, q_now, top_z, observed)
                if res is None:
                    continue
                any_ik = True
                if res == "collision":
                    hit = True
                    continue
                cost = float(np.abs(res[0] - q_now).max())
                if best is None or cost < best[0]:
                    best = (cost, g, res, flipped)
            if best is not None:
                _, g, (q_above, q_pre, q_grasp, q_lift, above, pre, lift), flipped = best
                tilt = float(np.arccos(np.clip(-g.R[2, 2], -1.0, 1.0)))
                open_w = float(min(GRIPPER_OPEN, widths[i] + self.open_margin))
                plan = GraspPlan(g, pre, lift, above, q_above, q_pre, q_grasp, q_lift, float(widths[i]), open_w,
                                 int(i), flipped, tilt, float(scores[i]))
                return PlanResult(plan, "ok", n, len(idx), n_tried, rejected)
            rejected["collision" if hit else "unreachable"] += 1
        return PlanResult(None, "no_feasible_grasp" if any_ik else "ik_failure", n, len(idx), n_tried, rejected)

    def _check(self, model, data, ids, task, g: Pose, q_now: np.ndarray, top_z: float,
               observed: _Obstacles | None = None):
        """IK (and collisions) of one grasp: ``None`` if IK fails, ``"collision"``, or the solutions."""
        pre = Pose(g.R, g.t - self.pregrasp * g.R[:, 2])
        # The lowest point of the open gripper (fingers and palm as boxes) must clear the object's top.
        drop = float(-(self._open_corners @ g.R.T)[:, 2].min())
        above = Pose(g.R, [pre.t[0], pre.t[1], max(pre.t[2], top_z + self.clearance + drop)])
        lift = Pose(g.R, g.t + np.array([0.0, 0.0, self.lift]))
        r_above = solve_ik(model, data, ids, above, q_now)
        if not r_above.success:
            return None
        r_pre = solve_ik(model, data, ids, pre, r_above.q)
        if not r_pre.success:
            return None
        r_grasp = solve_ik(model, data, ids, g, r_pre.q)
        if not r_grasp.success:
            return None
        r_lift = solve_ik(model, data, ids, lift, r_grasp.q)
        if not r_lift.success:
            return None
        if self.check_collisions and (self._collides(task, r_pre.q, observed)
                                     or self._collides(task, r_grasp.q, observed)):
            return "collision"
        return r_above.q, r_pre.q, r_grasp.q, r_lift.q, above, pre, lift

    def _collides(self, task, q: np.ndarray, observed: _Obstacles | None = None) -> bool:
        """Whether the robot at ``q`` with the gripper open penetrates anything but itself and the target
        (simulator geometry), or with ``observed``: the table (simulator geometry) or an observed obstacle
        point (inside the hand's or fingers' boxes grown by ``obstacle_margin``)."""
        model, ids = task.model, task.ids
        s = task.planning_data
        s.qpos[:] = task.data.qpos
        s.qpos[ids.arm_qpos] = q
        s.qpos[ids.finger_qpos] = GRIPPER_OPEN / 2
        mujoco.mj_fwdPosition(model, s)
        if observed is not None and len(observed.points) and points_in_geoms(
                model, s, observed.hand_geoms, observed.points, self.obstacle_margin).any():
            return True
        n = s.ncon
        if n == 0:
            return False
        geoms = np.asarray(s.contact.geom[:n])
        dist = np.asarray(s.contact.dist[:n])
        robot = np.isin(geoms, ids.robot_geoms)
        target = np.isin(geoms, task.target_geoms)
        hit = (robot[:, 0] ^ robot[:, 1]) & ~target.any(axis=1) & (dist < -0.001)
        if observed is not None:
            hit &= np.isin(geoms, observed.table_geoms).any(axis=1)
        return bool(hit.any())
