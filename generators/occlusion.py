"""Physical occlusion levels: a 3D occluder between the camera and a target, tuned until the target's
*measured* occluded fraction (``1 - visib_fract``, from the renderer's segmentation) lies in the level's band.

Levels and bands come from :data:`simtest.corrupt.occlusion.OCCLUSION_BANDS` (the object-fraction band of
each definition: OccludedPASCAL3D+ ``pascal3d+`` L1 20-40 %, L2 40-60 %, L3 60-80 %; or ``objectcentric``).
Unlike a 2D paste, the occluder is in the scene, so RGB, depth and masks all agree with it.

Two occluder kinds, tried in this order:

* ``standing``: a textured box standing on the table between the target and the camera; its height is
  bisected (more height, more occlusion).
* ``floating``: a plate facing the camera on the line of sight; its sideways offset is bisected (the further
  out, the less occlusion). It can reach any band, so it is the fallback when a standing box cannot (e.g. a
  camera looking almost straight down).

Every image records the requested level, the target, the occluded fraction reached and the measured level
of every instance (``scene_occlusion.json`` in the scene folder).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

import simtest  # noqa: F401
import mujoco

from simtest.camera import CameraModel
from simtest.corrupt.occlusion import OCCLUSION_BANDS
from simtest.generators.builder import N_OCCLUDERS, SimScene
from simtest.geometry import Pose
from simtest.render.rasterizer import Renderer

__all__ = ["OcclusionRecord", "measured_level", "occlude_view", "hide_occluders", "bisect_occlusion"]

_BISECT_STEPS = 10


@dataclass
class OcclusionRecord:
    """What occlusion one image got."""

    requested: str
    definition: str
    target_instance: int | None = None
    occluded_fraction: float | None = None
    in_band: bool = False
    kind: str | None = None  # "standing" | "floating" | None (L0 / no target)
    occluder_size: list[float] = field(default_factory=list)  # box half extents, metres
    occluder_pos: list[float] = field(default_factory=list)  # world, metres

    def to_dict(self, instance_to_gt: dict[int, int], levels: list[str]) -> dict:
        return {"requested": self.requested, "definition": self.definition,
                "target_gt_id": instance_to_gt.get(self.target_instance) if self.target_instance is not None
                else None,
                "occluded_fraction": self.occluded_fraction, "in_band": self.in_band, "occluder": self.kind,
                "occluder_half_size": self.occluder_size, "occluder_pos": self.occluder_pos,
                "measured_levels": levels}


def measured_level(occluded_fraction: float, definition: str = "pascal3d+") -> str:
    """Level name (``L0``..``L3``, ``L3+`` beyond L3's band) of an occluded fraction in [0, 1]."""
    bands = OCCLUSION_BANDS[definition]
    if occluded_fraction < bands[1][0][0]:
        return "L0"
    for level in (1, 2, 3):
        lo, hi = bands[level][0]
        if occluded_fraction < hi or level == 3 and occluded_fraction <= hi:
            return f"L{level}"
    return "L3+"


def bisect_occlusion(occluded_at, less: float, more: float, band: tuple[float, float], steps: int = _BISECT_STEPS,
                     tol: float = 0.05) -> tuple[float, float]:
    """Bisect an occluder parameter until the occluded fraction is near the middle of ``band``.

    Args:
        occluded_at: ``x -> occluded fraction`` in [0, 1]; places the occluder at ``x`` and measures (a render).
        less, more: Parameter values giving less and more occlusion (either order on the number line).
        band: ``(lo, hi)`` occluded-fraction band; the goal is its middle.
        steps: Maximum bisection steps.
        tol: Stop once within ``tol`` of the goal.

    Returns:
        ``(x, fraction)`` of the evaluated value closest to the goal; when even ``more`` stays below the band,
        ``(more, its fraction)`` without bisecting.
    """
    lo, hi = band
    goal = 0.5 * (lo + hi)
    best = (more, occluded_at(more))
    if best[1] < lo:
        return best
    a, b = less, more
    for _ in range(steps):
        mid = 0.5 * (a + b)
        f = occluded_at(mid)
        if abs(f - goal) < abs(best[1] - goal):
            best = (mid, f)
        if abs(f - goal) < tol:
            break
        if f < goal:
            a = mid
        else:
            b = mid
    return best


def _geoms(scene: SimScene) -> list[tuple[int, int, int]]:
    """(mocap id, geom id, body id) of each occluder."""
    m = scene.model
    out = []
    for k in range(N_OCCLUDERS):
        b = mujoco.mj_name2id(m, mujoco.mjtObj.mjOBJ_BODY, f"occluder_{k}")
        if b >= 0:
            out.append((int(m.body_mocapid[b]), int(m.body_geomadr[b]), b))
    return out


def hide_occluders(scene: SimScene) -> None:
    for k, (mid, _, _) in enumerate(_geoms(scene)):
        scene.data.mocap_pos[mid] = [500.0, 600.0 + k, -500.0]
    mujoco.mj_kinematics(scene.model, scene.data)


def _place(scene: SimScene, camera: CameraModel, half: np.ndarray, pos: np.ndarray, R: np.ndarray) -> None:
    mid, g, _ = _geoms(scene)[0]
    scene.model.geom_size[g] = half
    scene.model.geom_rbound[g] = float(np.linalg.norm(half))
    scene.data.mocap_pos[mid] = pos
    scene.data.mocap_quat[mid] = Pose(R, pos).quat_wxyz()
    mujoco.mj_kinematics(scene.model, scene.data)
    scene.set_camera(camera)


def _visible_counts(scene: SimScene, renderer: Renderer) -> np.ndarray:
    seg = renderer.render(scene.data, scene.camera_id, rgb=False, depth=False).seg
    inst = scene.geom_instance[np.clip(seg, 0, None)]
    inst = inst[(seg >= 0) & (inst >= 0)]
    return np.bincount(inst, minlength=len(scene.instance_obj_ids))


def occlude_view(scene: SimScene, camera: CameraModel, renderer: Renderer, level: str, definition: str,
                 px_count_all: dict[int, int], table_height: float, rng: np.random.Generator,
                 standing_first: bool = True, band: tuple[float, float] | None = None) -> OcclusionRecord:
    """Place the occluder for one view so that a target's occluded fraction lies in ``level``'s band (or in
    ``band``).

    Args:
        scene: Settled scene; its occluder body is moved (and left in place for rendering).
        camera: The view's camera.
        renderer: A renderer of ``scene.model`` (segmentation passes only).
        level: ``"L0".."L3"``; L0 hides the occluder.
        definition: Band definition (``pascal3d+`` or ``objectcentric``).
        px_count_all: Amodal pixel count of each active instance at this view (from the annotator).
        table_height: Table top height (metres).
        rng: The scene's generator.
        standing_first: Try a standing box before a floating plate.
        band: ``(lo, hi)`` occluded fraction in [0, 1] to aim at instead of ``level``'s band (``level`` is then
            only the name recorded); a band ending at 0 places no occluder.
    """
    rec = OcclusionRecord(level, definition)
    hide_occluders(scene)
    scene.set_camera(camera)
    if (level == "L0" and band is None) or (band is not None and band[1] <= 0.0) or not _geoms(scene):
        return rec
    lo, hi = band if band is not None else OCCLUSION_BANDS[definition][int(level[1])][0]
    visible = _visible_counts(scene, renderer)
    # Target: the most visible instance that is mostly in view (its visible fraction is what we lower).
    cands = [(visible[i] / px_count_all[i], visible[i], i) for i in px_count_all
             if px_count_all[i] > 0 and visible[i] >= 50]
    cands = [c for c in cands if c[0] >= 0.9] or cands
    if not cands:
        return rec
    frac0, _, target = max(cands)
    rec.target_instance = target
    _, t_obj = scene.object_pose_world(target)
    # Bounding radius of the target's visual mesh (its geom frame sits near the model origin).
    obj_radius = max(float(scene.model.geom_rbound[scene.model.body_geomadr[scene.instance_bodies[target]]]), 0.02)
    eye = camera.T_world_cam.t
    n_all = px_count_all[target]

    def occluded() -> float:
        return 1.0 - _visible_counts(scene, renderer)[target] / n_all

    kinds = (["standing"] if standing_first else []) + ["floating"]
    for kind in kinds:
        if kind == "standing":
            to_cam = eye[:2] - t_obj[:2]
            dist = float(np.linalg.norm(to_cam))
            if dist < 1e-6:
                continue
            u = to_cam / dist
            side = np.array([-u[1], u[0]])
            gap = obj_radius + rng.uniform(0.02, 0.08)
            if gap > dist - 0.05:
                continue
            width = obj_radius * rng.uniform(1.6, 3.0)
            thick = rng.uniform(0.01, 0.03)
            lateral = rng.uniform(-0.4, 0.4) * width
            centre_xy = t_obj[:2] + u * gap + side * lateral
            yaw = np.arctan2(u[1], u[0])
            R = np.array([[np.cos(yaw), -np.sin(yaw), 0.0], [np.sin(yaw), np.cos(yaw), 0.0], [0.0, 0.0, 1.0]])
            h_max = max(0.02, min(eye[2] - table_height - 0.05, 0.6))

            def place(s: float) -> None:  # s in [0, 1]: the box's height as a fraction of h_max
                h = max(s * h_max, 1e-3)
                _place(scene, camera, np.array([thick / 2, width / 2, h / 2]),
                       np.array([centre_xy[0], centre_xy[1], table_height + h / 2]), R)
            less, more = 0.0, 1.0
        else:
            d = float(np.linalg.norm(t_obj - eye))
            alpha = rng.uniform(0.35, 0.65)  # plate position along the line of sight
            half_w = obj_radius * alpha * rng.uniform(1.3, 2.0)
            view = (t_obj - eye) / d
            R = camera.T_world_cam.R  # plate faces the camera (its x, y along the image axes)
            ang = rng.uniform(0, 2 * np.pi)
            direction = R @ np.array([np.cos(ang), np.sin(ang), 0.0])
            span = 2.0 * half_w + obj_radius * alpha

            def place(s: float) -> None:  # s = 0: plate centred on the line of sight; 1: fully aside
                pos = eye + view * d * alpha + direction * (span * s)
                _place(scene, camera, np.array([half_w, half_w, 0.003]), pos, R)
            less, more = 1.0, 0.0

        def occluded_at(s: float) -> float:
            place(s)
            return occluded()

        s_best, f_best = bisect_occlusion(occluded_at, less, more, (lo, hi))
        if kind == "standing" and f_best < lo:
            continue  # too short even at full height: try the floating plate
        place(s_best)
        rec.kind = kind
        rec.occluded_fraction = float(f_best)
        rec.in_band = bool(lo <= f_best <= hi)
        mid_, g, _ = _geoms(scene)[0]
        rec.occluder_size = [float(v) for v in scene.model.geom_size[g]]
        rec.occluder_pos = [float(v) for v in scene.data.mocap_pos[mid_]]
        if rec.in_band:
            return rec
    return rec
    return rec
