"""``Annotator``: ground truth for one rendered view.

* Poses: ``T_cam_obj = T_cam_world @ T_world_obj`` with the camera in OpenCV convention.
* Visible masks: exact, from the renderer's per-geom segmentation ids (no depth thresholds).
* Amodal masks: the object's front-facing triangles projected with K and filled with the same pixel-centre
  rule as the GL rasterizer, on a canvas grown to hold the whole silhouette, so ``px_count_all`` includes
  pixels outside the image.
"""

from __future__ import annotations

import weakref
from dataclasses import dataclass

import numpy as np

from simtest.camera import CameraModel
from simtest.generators.builder import SceneState, SimScene
from simtest.geometry import Pose
from simtest.io.bop import mask_bbox
from simtest.objects import ObjectSet
from simtest.render.rasterizer import Frame

__all__ = ["InstanceAnnotation", "annotate", "amodal_counts", "rasterize_silhouette"]


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


def rasterize_silhouette(uv: np.ndarray, tris: np.ndarray) -> tuple[np.ndarray, tuple[int, int]]:
    """Fill the union of projected triangles with the pixel-centre rule (pixel (x, y) samples point (x, y)).

    Uses the non-zero winding rule over the triangles' oriented edges, scanline by scanline: each triangle adds
    +1 (or -1, by its 2D orientation) inside itself, so with every triangle oriented the same way (front faces
    of a closed mesh) the union is where the winding number is non-zero. Edges shared by two triangles cancel.
    Cost grows with the edge count and the rows they span, not with the filled area.

    Args:
        uv: (N, 2) projected vertex positions in pixels (OpenCV: pixel centres at integers).
        tris: (M, 3) vertex indices of the triangles to fill, all with the same 2D orientation.

    Returns:
        ``(mask, (x0, y0))``: a bool mask over the triangles' pixel bounding box and the pixel coordinates of
        its top-left element (may be 0x0).
    """
    if len(tris) == 0:
        return np.zeros((0, 0), dtype=bool), (0, 0)
    topology = EdgeTopology(tris)
    return _fill(uv, tris, topology, np.arange(len(tris)), np.ones(len(tris), dtype=np.int64))


class EdgeTopology:
    """The undirected edges of a triangle mesh and, per face, which edges it uses in which direction.

    A face ``(a, b, c)`` uses edges ``a -> b``, ``b -> c``, ``c -> a``; :attr:`face_edge` holds their indices into
    :attr:`edges` (``lo < hi`` pairs, sorted) and :attr:`face_sign` +1 where the face runs ``lo -> hi``, else -1.
    Summing the signs of a set of faces per edge gives each edge's net winding weight, without sorting the faces'
    edges again for every view.
    """

    def __init__(self, faces: np.ndarray) -> None:
        faces = np.asarray(faces, dtype=np.int64)
        a = faces.reshape(-1)
        b = faces[:, [1, 2, 0]].reshape(-1)
        lo, hi = np.minimum(a, b), np.maximum(a, b)
        base = int(hi.max()) + 1 if len(hi) else 1
        uniq, inv = np.unique(lo * base + hi, return_inverse=True)  # sorted by (lo, hi)
        self.edges = np.stack([uniq // base, uniq % base], axis=1)
        self.face_edge = inv.reshape(-1, 3)
        self.face_sign = np.where(a < b, 1, -1).reshape(-1, 3)


def edge_topology(obj) -> EdgeTopology:
    """The :class:`EdgeTopology` of ``obj.faces``, made once per object model (its mesh is read-only) and
    dropped with the model."""
    entry = _TOPOLOGY.get(id(obj))
    if entry is None or entry[0]() is not obj:
        key = id(obj)
        entry = (weakref.ref(obj), EdgeTopology(obj.faces))
        _TOPOLOGY[key] = entry
        weakref.finalize(obj, _TOPOLOGY.pop, key, None)
    return entry[1]


#: ``{id(object model): (weak reference to the model, its EdgeTopology)}``.
_TOPOLOGY: dict[int, tuple] = {}


def _fill(uv: np.ndarray, faces: np.ndarray, topology: EdgeTopology, sel: np.ndarray, orient: np.ndarray
          ) -> tuple[np.ndarray, tuple[int, int]]:
    """:func:`rasterize_silhouette` of faces ``sel`` of ``faces`` (their edges in ``topology``), each turned by
    ``orient`` (+1 as stored, -1 reversed) so that all have the same 2D orientation."""
    if len(sel) == 0:
        return np.zeros((0, 0), dtype=bool), (0, 0)
    p = uv[faces[sel]]
    x0 = int(np.ceil(p[..., 0].min() - 1e-9))
    y0 = int(np.ceil(p[..., 1].min() - 1e-9))
    x1 = int(np.floor(p[..., 0].max() + 1e-9))
    y1 = int(np.floor(p[..., 1].max() + 1e-9))
    if x1 < x0 or y1 < y0:
        return np.zeros((0, 0), dtype=bool), (0, 0)
    # Net winding weight per undirected edge lo -> hi; an edge used in both directions (shared by two of the
    # faces) cancels out.
    signs = topology.face_sign[sel] * orient[:, None]
    net = np.bincount(topology.face_edge[sel].reshape(-1), weights=signs.reshape(-1),
                      minlength=len(topology.edges)).astype(np.int64)
    keep = np.flatnonzero(net)
    ea, eb, w = topology.edges[keep, 0], topology.edges[keep, 1], net[keep]
    pa, pb = uv[ea], uv[eb]
    # Canonical direction per edge (upward in y) so equal edges give bit-identical crossings.
    up = pa[:, 1] <= pb[:, 1]
    s = np.where(up[:, None], pa, pb)
    e = np.where(up[:, None], pb, pa)
    w = np.where(up, w, -w)
    r0 = np.ceil(s[:, 1]).astype(np.int64)  # rows with s.y <= row < e.y (half-open: vertices count once)
    r1 = np.ceil(e[:, 1]).astype(np.int64)
    n = np.maximum(r1 - r0, 0)
    sel_e = n > 0
    s, e, w, r0, n = s[sel_e], e[sel_e], w[sel_e], r0[sel_e], n[sel_e]
    idx = np.repeat(np.arange(len(n)), n)
    rows = r0[idx] + (np.arange(int(n.sum())) - np.repeat(np.cumsum(n) - n, n))
    t = (rows - s[idx, 1]) / (e[idx, 1] - s[idx, 1])
    xc = s[idx, 0] + t * (e[idx, 0] - s[idx, 0])
    col = np.clip(np.ceil(xc).astype(np.int64) - x0, 0, x1 - x0 + 1)
    H, W = y1 - y0 + 1, x1 - x0 + 1
    # Winding steps summed per pixel (small integers: exact in float64), then summed along each row. A winding
    # number is at most the triangle count in size, a step between two pixels twice that: 16 bits hold both
    # exactly below 2^14 triangles (and sum faster than 32).
    diff = np.bincount((rows - y0) * (W + 1) + col, weights=w[idx], minlength=H * (W + 1)).reshape(H, W + 1)
    dtype = np.int16 if len(sel) < 2**14 else np.int32
    mask = np.cumsum(diff[:, :W].astype(dtype), axis=1, dtype=dtype) != 0
    return mask, (x0, y0)


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
    faces = obj.faces
    pa, pb, pc = uv[faces[:, 0]], uv[faces[:, 1]], uv[faces[:, 2]]
    area2 = (pb[:, 0] - pa[:, 0]) * (pc[:, 1] - pa[:, 1]) - (pb[:, 1] - pa[:, 1]) * (pc[:, 0] - pa[:, 0])
    in_front = np.all(z[faces] > near, axis=1)
    if obj.is_watertight:  # front faces (positive 2D orientation): for a closed mesh their union is the silhouette
        sel = np.flatnonzero(in_front & (area2 > 0))
        orient = np.ones(len(sel), dtype=np.int64)
    else:  # open mesh: fill every face, each turned to the same orientation
        sel = np.flatnonzero(in_front & (area2 != 0))
        orient = np.where(area2[sel] > 0, 1, -1)
    sil, origin = _fill(uv, faces, edge_topology(obj), sel, orient)
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
