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
from simtest.generators.builder import SimScene
from simtest.geometry import Pose
from simtest.objects import ObjectSet
from simtest.render import Frame

__all__ = ["InstanceAnnotation", "annotate", "rasterize_silhouette"]


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
        bbox_obj: [x, y, w, h] of the silhouette (may extend beyond the image), [-1]*4 if empty.
        bbox_visib: [x, y, w, h] of the visible mask, [-1]*4 if empty.
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


def rasterize_silhouette(uv: np.ndarray, tris: np.ndarray) -> tuple[np.ndarray, tuple[int, int]]:
    """Fill projected triangles with the pixel-centre rule (pixel (x, y) covers the point (x, y)).

    Args:
        uv: (N, 2) projected vertex positions in pixels (OpenCV: pixel centres at integers).
        tris: (M, 3) vertex indices of the triangles to fill.

    Returns:
        ``(mask, (x0, y0))``: a bool mask over the triangles' pixel bounding box and the pixel coordinates of
        its top-left element. Empty triangles are ignored; the mask may be 0x0.
    """
    if len(tris) == 0:
        return np.zeros((0, 0), dtype=bool), (0, 0)
    p = uv[tris]  # (M, 3, 2)
    lo = np.ceil(p.min(axis=1) - 1e-9).astype(np.int64)
    hi = np.floor(p.max(axis=1) + 1e-9).astype(np.int64)
    keep = np.all(hi >= lo, axis=1)
    p, lo, hi = p[keep], lo[keep], hi[keep]
    if len(p) == 0:
        return np.zeros((0, 0), dtype=bool), (0, 0)
    x0, y0 = lo.min(axis=0)
    x1, y1 = hi.max(axis=0)
    mask = np.zeros((y1 - y0 + 1, x1 - x0 + 1), dtype=bool)
    w = hi[:, 0] - lo[:, 0] + 1
    h = hi[:, 1] - lo[:, 1] + 1
    counts = w * h
    # Big triangles are few: fill them with OpenCV-free exact tests in chunks to bound memory.
    order = np.argsort(counts)
    p, lo, w, h, counts = p[order], lo[order], w[order], h[order], counts[order]
    csum = np.cumsum(counts)
    start = 0
    budget = 2_000_000
    while start < len(p):
        end = int(np.searchsorted(csum, (csum[start - 1] if start else 0) + budget, side="right"))
        end = max(end, start + 1)
        _fill(mask, p[start:end], lo[start:end], w[start:end], counts[start:end], x0, y0)
        start = end
    return mask, (int(x0), int(y0))


def _fill(mask, p, lo, w, counts, x0, y0) -> None:
    tri = np.repeat(np.arange(len(p)), counts)
    first = np.cumsum(counts) - counts
    local = np.arange(int(counts.sum())) - np.repeat(first, counts)
    px = lo[tri, 0] + local % w[tri]
    py = lo[tri, 1] + local // w[tri]
    a, b, c = p[tri, 0], p[tri, 1], p[tri, 2]

    def edge(v0, v1):
        return (v1[:, 0] - v0[:, 0]) * (py - v0[:, 1]) - (v1[:, 1] - v0[:, 1]) * (px - v0[:, 0])

    e0, e1, e2 = edge(a, b), edge(b, c), edge(c, a)
    inside = ((e0 >= 0) & (e1 >= 0) & (e2 >= 0)) | ((e0 <= 0) & (e1 <= 0) & (e2 <= 0))
    mask[py[inside] - y0, px[inside] - x0] = True


def _bbox(mask: np.ndarray, x0: int = 0, y0: int = 0) -> list[int]:
    ys = np.flatnonzero(mask.any(axis=1))
    if len(ys) == 0:
        return [-1, -1, -1, -1]
    xs = np.flatnonzero(mask.any(axis=0))
    return [int(xs[0] + x0), int(ys[0] + y0), int(xs[-1] - xs[0] + 1), int(ys[-1] - ys[0] + 1)]


def annotate(scene: SimScene, frame: Frame, camera: CameraModel, objects: ObjectSet,
             near: float = 0.01) -> list[InstanceAnnotation]:
    """Annotate every active instance of ``scene`` in ``frame`` seen by ``camera``.

    Args:
        scene: The settled scene at the state that was rendered.
        frame: The rendered frame (needs ``seg`` and ``depth``).
        camera: The camera that rendered it (``T_world_cam`` in OpenCV convention).
        objects: The object set (meshes for the silhouettes).
        near: Triangles with a vertex closer than this (metres) are not rasterized.
    """
    H, W = camera.height, camera.width
    T_cam_world = camera.T_cam_world
    inst = scene.geom_instance
    seg = frame.seg
    seg_inst = np.where(seg >= 0, inst[np.clip(seg, 0, None)], -1)
    out = []
    for i, oid in enumerate(scene.instance_obj_ids):
        if not scene.active[i]:
            continue
        obj = objects.get(oid)
        R, t = scene.object_pose_world(i)
        T = T_cam_world @ Pose(R, t)
        v_cam = T.apply(obj.vertices)
        uv, z = camera.project(v_cam)
        faces = obj.faces
        fz = z[faces]
        ok = np.all(fz > near, axis=1)
        # Front faces only: for a closed mesh their union is the silhouette, at half the work.
        f = faces[ok]
        a, b, c = v_cam[f[:, 0]], v_cam[f[:, 1]], v_cam[f[:, 2]]
        normal = np.cross(b - a, c - a)
        # Keep faces up to slightly past edge-on, so float error never drops a silhouette face.
        cos = np.einsum("ij,ij->i", normal, a)
        front = cos < 1e-3 * np.linalg.norm(normal, axis=1) * np.linalg.norm(a, axis=1)
        sil, (x0, y0) = rasterize_silhouette(uv, f[front] if obj.is_watertight else f)
        px_all = int(sil.sum())
        mask = np.zeros((H, W), dtype=bool)
        if sil.size:
            ys0, xs0 = max(0, y0), max(0, x0)
            ys1, xs1 = min(H, y0 + sil.shape[0]), min(W, x0 + sil.shape[1])
            if ys1 > ys0 and xs1 > xs0:
                mask[ys0:ys1, xs0:xs1] = sil[ys0 - y0:ys1 - y0, xs0 - x0:xs1 - x0]
        visib = seg_inst == i
        # The amodal mask contains the visible one by definition; GL's sub-pixel vertex snapping can leave a
        # rare pixel centre that sits within 1/256 px of a vertex covered in the render but not in the fill.
        extra = visib & ~mask
        if extra.any():
            mask |= extra
            px_all += int(extra.sum())
        px_visib = int(visib.sum())
        px_valid = int(np.count_nonzero(mask & (frame.depth > 0)))
        out.append(InstanceAnnotation(
            obj_id=oid, T_cam_obj=T, mask=mask, mask_visib=visib, px_count_all=px_all,
            px_count_valid=px_valid, px_count_visib=px_visib,
            visib_fract=float(px_visib / px_all) if px_all > 0 else 0.0,
            bbox_obj=_bbox(sil, x0, y0), bbox_visib=_bbox(visib)))
    return out
