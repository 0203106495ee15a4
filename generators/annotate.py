"""``Annotator``: ground truth for one rendered view.

* Poses: ``T_cam_obj = T_cam_world @ T_world_obj`` with the camera in OpenCV convention.
* Visible masks: exact, from the renderer's per-geom segmentation ids (no depth thresholds).
* Amodal masks: the object's front-facing triangles projected with K and filled with the same pixel-centre
  rule as the GL rasterizer, on a canvas grown to hold the whole silhouette, so ``px_count_all`` includes
  pixels outside the image.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from simtest.camera import CameraModel
from simtest.generators.builder import SceneState, SimScene
from simtest.geometry import Pose
from simtest.io.bop import mask_bbox
from simtest.objects import ObjectSet
from simtest.render.rasterizer import Frame
from simtest.render.silhouette import edge_topology, fill_faces, front_faces

__all__ = ["InstanceAnnotation", "annotate", "amodal_counts"]


@dataclass(frozen=True)
class InstanceAnnotation:
    """Ground truth of one object instance in one image (pixels, metres).

    Attributes:
        obj_id: Object id.
        T_cam_obj: Pose of the object model frame in the OpenCV camera frame.
        mask: (H, W) bool amodal silhouette cropped to the image.
        mask_visib: (H, W) bool visible pixels.
        px_count_all: Silhouette pixels including those outside the image.
        px_count_valid: Silhouette pixels (in the image) with valid depth.
        px_count_visib: Visible pixels.
        visib_fract: ``px_count_visib / px_count_all`` (0 if the object is not in front of the camera).
        bbox_obj: [x, y, w, h] of the silhouette (may extend beyond the image), [-1]*4 if empty; BOP's
            convention (:func:`simtest.io.bop.mask_bbox`: ``w = xmax - xmin``, ``h = ymax - ymin``).
        bbox_visib: [x, y, w, h] of the visible mask (same convention), [-1]*4 if empty.
    """

    obj_id: int
    T_cam_obj: Pose
    mask: np.ndarray
    mask_visib: np.ndarray
    px_count_all: int
    px_count_valid: int
    px_count_visib: int
    visib_fract: float
    bbox_obj: list[int]
    bbox_visib: list[int]
    instance: int = -1  # index of the instance in the scene


def _box_union(a: list[int], b: list[int]) -> list[int]:
    """Smallest BOP box ``[x, y, w, h]`` (pixels) holding boxes ``a`` and ``b`` (``w < 0``: empty box)."""
    if a[2] < 0 or b[2] < 0:
        return list(b if a[2] < 0 else a)
    x0, y0 = min(a[0], b[0]), min(a[1], b[1])
    x1, y1 = max(a[0] + a[2], b[0] + b[2]), max(a[1] + a[3], b[1] + b[3])
    return [x0, y0, x1 - x0, y1 - y0]


def _silhouette(scene: SimScene | SceneState, i: int, obj, camera: CameraModel, T_cam_world: Pose, near: float):
    """(T_cam_obj, silhouette mask over its pixel bbox, (x0, y0)) of instance ``i``."""
    R, t = scene.object_pose_world(i)
    T = T_cam_world @ Pose(R, t)
    uv, z = camera.project(T.apply(obj.vertices))
    sel, orient = front_faces(obj, uv, z, near)
    sil, origin = fill_faces(uv, obj.faces, edge_topology(obj), sel, orient)
    return T, sil, origin


def amodal_counts(scene: SimScene | SceneState, camera: CameraModel, objects: ObjectSet, near: float = 0.01) -> dict[int, int]:
    """``{instance: px_count_all}`` of every active instance seen by ``camera`` (no rendering needed)."""
    T_cam_world = camera.T_cam_world
    return {i: int(_silhouette(scene, i, objects.get(oid), camera, T_cam_world, near)[1].sum())
            for i, oid in enumerate(scene.instance_obj_ids) if scene.active[i]}


def annotate(scene: SimScene | SceneState, frame: Frame, camera: CameraModel, objects: ObjectSet,
             near: float = 0.01) -> list[InstanceAnnotation]:
    """Annotate every active instance of ``scene`` in ``frame`` seen by ``camera``.

    Args:
        scene: The settled scene at the state that was rendered, or that state (:meth:`SimScene.state`).
        frame: The rendered frame (needs ``seg`` and ``depth``).
        camera: The camera that rendered it (``T_world_cam`` in OpenCV convention).
        objects: The object set (meshes for the silhouettes).
        near: Triangles with a vertex closer than this (metres) are not rasterized.
    """
    H, W = camera.height, camera.width
    T_cam_world = camera.T_cam_world
    # Instance index per pixel in one lookup: entry g is geom g's, the last entry (index -1) the background's.
    lut = np.append(scene.geom_instance, -1).astype(np.int16 if len(scene.instance_obj_ids) < 2**15 else np.int32)
    seg_inst = lut[frame.seg]
    out = []
    for i, oid in enumerate(scene.instance_obj_ids):
        if not scene.active[i]:
            continue
        T, sil, (x0, y0) = _silhouette(scene, i, objects.get(oid), camera, T_cam_world, near)
        px_all = int(sil.sum())
        mask = np.zeros((H, W), dtype=bool)
        visib = np.zeros((H, W), dtype=bool)
        # Work inside the silhouette's box grown by 2 px (visible pixels lie inside the silhouette, up to
        # GL's sub-pixel vertex snapping), clipped to the image.
        ys0, xs0 = max(0, y0 - 2), max(0, x0 - 2)
        ys1, xs1 = min(H, y0 + sil.shape[0] + 2), min(W, x0 + sil.shape[1] + 2)
        if sil.size and ys1 > ys0 and xs1 > xs0:
            a0, b0 = max(ys0, y0), max(xs0, x0)
            a1, b1 = min(ys1, y0 + sil.shape[0]), min(xs1, x0 + sil.shape[1])
            if a1 > a0 and b1 > b0:
                mask[a0:a1, b0:b1] = sil[a0 - y0:a1 - y0, b0 - x0:b1 - x0]
            visib[ys0:ys1, xs0:xs1] = seg_inst[ys0:ys1, xs0:xs1] == i
        # The amodal mask contains the visible one by definition; GL's sub-pixel vertex snapping can leave a
        # rare pixel centre that sits within 1/256 px of a vertex covered in the render but not in the fill.
        # Visible pixels lie inside the work box, so the union is taken there.
        bbox_obj = mask_bbox(sil, x0, y0)
        if ys1 > ys0 and xs1 > xs0:
            box = (slice(ys0, ys1), slice(xs0, xs1))
            extra = visib[box] & ~mask[box]
            if extra.any():
                mask[box] |= extra
                px_all += int(extra.sum())
                bbox_obj = _box_union(bbox_obj, mask_bbox(extra, xs0, ys0))
        px_visib = int(visib[ys0:ys1, xs0:xs1].sum()) if ys1 > ys0 and xs1 > xs0 else 0
        px_valid = int(np.count_nonzero(mask[ys0:ys1, xs0:xs1] & (frame.depth[ys0:ys1, xs0:xs1] > 0))) \
            if ys1 > ys0 and xs1 > xs0 else 0
        out.append(InstanceAnnotation(
            obj_id=oid, T_cam_obj=T, mask=mask, mask_visib=visib, px_count_all=px_all,
            px_count_valid=px_valid, px_count_visib=px_visib,
            visib_fract=float(px_visib / px_all) if px_all > 0 else 0.0,
            bbox_obj=bbox_obj,
            bbox_visib=mask_bbox(visib[ys0:ys1, xs0:xs1], xs0, ys0) if px_visib else [-1, -1, -1, -1], instance=i))
    return out
