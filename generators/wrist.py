"""The wrist rig: the camera rides on the Panda hand, at reachable arm configurations looking at the table."""

from __future__ import annotations

import numpy as np

from simtest.camera import CameraModel
from simtest.errors import DatasetError
from simtest.generators.config import GenerateConfig

__all__ = ["wrist_cameras"]


def wrist_cameras(cfg: GenerateConfig, scene, poi: np.ndarray, base: CameraModel
                  ) -> list[tuple[CameraModel, np.ndarray]]:
    """One (camera, arm configuration) per frame: IK puts the wrist camera on a view of ``poi``.

    Distances come from ``cfg.shell.distance`` (clipped to the arm's reach, 0.2-0.7 m) and elevations from
    ``cfg.shell.elevation_deg``. The returned camera is where the wrist camera is at that configuration.
    """
    from simtest.errors import ConfigError
    from simtest.robot import sample_wrist_views, wrist_camera_model

    ids = scene.panda
    lo = float(np.clip(cfg.shell.distance[0], 0.2, 0.7))
    hi = float(np.clip(cfg.shell.distance[1], lo, 0.7))
    el = np.deg2rad(np.clip(cfg.shell.elevation_deg, 15.0, 89.0))
    try:
        qs = sample_wrist_views(scene.model, scene.data, ids, poi, scene.rng, cfg.frames_per_scene, (lo, hi),
                                elevation_range=(float(el[0]), float(el[1])))
    except ConfigError as exc:
        raise DatasetError(f"scene {scene.spec.scene_index}: the wrist camera cannot reach "
                           f"{cfg.frames_per_scene} views of the objects: {exc}") from exc
    out = []
    for q in qs:
        scene.set_arm(q)
        cam = wrist_camera_model(scene.data, ids)
        out.append((base.with_pose(cam.T_world_cam), np.asarray(q)))
    return out
