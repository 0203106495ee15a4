"""The wrist observations of grasp episodes written as a BOP dataset (``simtest grasp --save-observations``).

Each episode becomes one scene of the split ``test`` (scene id = episode index), each capture of the episode one
image of it: the RGB and depth the estimator saw (``depth/``; with a depth sensor the exact depth goes to
``depth_exact/``), the camera, and every instance's ground truth at the capture (poses, amodal and visible masks,
boxes; :func:`simtest.generators.annotate.annotate`, as datasets are annotated). The object set is written to
``models/`` once, so ``simtest eval`` scores the folder and ``simtest show`` draws it like any dataset::

    OUT/observations/models/...            the object set (BOP models, models_info.json)
    OUT/observations/test/000003/...       episode 3's captures (rgb/, depth/, mask/, mask_visib/, scene_*.json)

Units: depth in metres in memory, ``depth_scale`` millimetres per PNG unit on disk.
"""

from __future__ import annotations

from pathlib import Path

from simtest.envs.observation import Capture
from simtest.generators.annotate import annotate
from simtest.camera import CameraModel
from simtest.io.bop import SceneWriter, write_camera_json
from simtest.io.bop_models import write_bop_models
from simtest.objects import ObjectSet

__all__ = ["OBSERVATIONS_FOLDER", "OBSERVATIONS_SPLIT", "DEPTH_SCALE", "write_observation_models",
           "write_observation_scene"]

#: Folder of a grasp run's output that holds the observation dataset.
OBSERVATIONS_FOLDER = "observations"
#: Split the episodes are written to.
OBSERVATIONS_SPLIT = "test"
#: Millimetres per depth PNG unit (as datasets write theirs).
DEPTH_SCALE = 0.1


def write_observation_models(objects: ObjectSet, camera: CameraModel, root: str | Path) -> Path:
    """Write the dataset-wide files of the observation dataset at ``root``: ``objects`` as its BOP models and
    ``camera`` (the wrist camera's intrinsics) as ``camera.json``; returns ``root/models``."""
    root = Path(root)
    root.mkdir(parents=True, exist_ok=True)
    write_camera_json(root / "camera.json", camera, DEPTH_SCALE)
    return write_bop_models(objects, root / "models")


def write_observation_scene(captures: list[Capture], objects: ObjectSet, root: str | Path, scene_id: int,
                            sensed_depth: bool = False) -> Path:
    """Write one episode's ``captures`` as scene ``scene_id`` of the ``test`` split under ``root``.

    Args:
        captures: The episode's captures in order (``GraspTask.captures``).
        objects: The object set of the episode.
        root: The observation dataset folder (``OUT/observations``).
        scene_id: The scene id (the episode index), >= 0.
        sensed_depth: The captures' depth is a depth sensor's: the exact depth is written to ``depth_exact/``.

    Returns:
        The scene folder.
    """
    split = Path(root) / OBSERVATIONS_SPLIT
    split.mkdir(parents=True, exist_ok=True)
    writer = SceneWriter(split, int(scene_id), depth_scale=DEPTH_SCALE, rgb_format="png")
    try:
        for im_id, cap in enumerate(captures):
            anns = annotate(cap.state, cap.frame, cap.camera, objects)
            writer.add(im_id, cap.rgb, cap.depth, cap.camera, anns, [a.mask for a in anns],
                       [a.mask_visib for a in anns])
            if sensed_depth:
                writer.add_depth("depth_exact", im_id, cap.frame.depth)
    except BaseException:
        writer.discard()
        raise
    return writer.close()
