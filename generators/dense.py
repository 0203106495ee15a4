"""Dense ground truth of one view from the exact geometry: instance maps, object coordinates, surface normals,
forward flow and 2D keypoints with visibility.

Everything starts from what the masks and depth already come from: the renderer's per-geom segmentation (which
geom each pixel sees) and its exact planar depth at the pixel centre (on the model surface to ~0.02 mm), the
geoms' world poses at the moment the view was rendered, and the meshes MuJoCo drew. No colour render is read.

* ``instances``: the visible masks of :func:`simtest.generators.annotate.annotate`, as one map.
* ``coords``: the pixel centre back-projected at its depth, mapped into the model frame by the GT pose.
* ``normals``: the geometric normal of the surface the pixel sees, in the OpenCV camera frame: analytic for
  MuJoCo's primitives (plane, box, sphere, capsule, cylinder, ellipsoid) from the point in the geom's frame;
  for meshes the normal of the triangle that contains the point (nearest triangle centroids as candidates,
  the exact containing triangle chosen by its plane and edges).
* ``flow``: each pixel's surface point carried with its geom to the next view (world pose of that geom at each
  moment), projected by the next camera; valid where the next view sees the same geom at that depth.
* ``keypoints``: each object's keypoints (8 bbox corners, then the farthest-point surface keypoints) projected
  with the GT pose; visibility 2 where the instance map shows the instance at that pixel with the keypoint's
  depth, 1 inside the image but hidden, 0 outside.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from simtest.camera import CameraModel, pinhole_pixels, pinhole_points

__all__ = ["CHANNELS", "ViewGeometry", "view_geometry", "instance_map", "object_coords", "surface_normals",
           "forward_flow", "keypoints_2d", "KEYPOINT_DEPTH_TOL_M", "FLOW_DEPTH_TOL"]

#: Every channel ``annotation.channels`` may ask for.
CHANNELS = ("instances", "coords", "normals", "flow", "keypoints")
#: A keypoint counts as visible when the depth at its pixel is within this (metres) of its own depth.
KEYPOINT_DEPTH_TOL_M = 0.005
#: A flow target counts as visible when the next view's depth there is within this fraction of its depth.
FLOW_DEPTH_TOL = 0.01
_MESH = 7


@dataclass(frozen=True)
class ViewGeometry:
    """What the channels need of one rendered view (pixels, metres).

    Attributes:
        camera: The view's camera (K, ``T_world_cam``).
        depth: (H, W) exact planar depth, 0 where nothing is hit.
        seg: (H, W) geom id per pixel, -1 for background.
        geom_xpos, geom_xmat: World poses of every geom at that moment ((ngeom, 3), (ngeom, 3, 3)).
        points_cam: (H, W, 3) the pixel centres back-projected at their depth (camera frame).
    """

    camera: CameraModel
    depth: np.ndarray
    seg: np.ndarray
    geom_xpos: np.ndarray
    geom_xmat: np.ndarray
    points_cam: np.ndarray


def view_geometry(camera: CameraModel, depth: np.ndarray, seg: np.ndarray, geom_xpos: np.ndarray,
                  geom_xmat: np.ndarray) -> ViewGeometry:
    """Bundle one view and back-project its pixel centres."""
    H, W = depth.shape
    v, u = np.mgrid[0:H, 0:W]
    z = np.asarray(depth, np.float64)
    pts = pinhole_points(camera.K, u, v, z)
    return ViewGeometry(camera, z, np.asarray(seg), np.asarray(geom_xpos, np.float64).reshape(-1, 3),
                        np.asarray(geom_xmat, np.float64).reshape(-1, 3, 3), pts)


def instance_map(masks_visib: list[np.ndarray], shape: tuple[int, int]) -> np.ndarray:
    """(H, W) uint16: 0 background, ``k + 1`` where the ``k``-th visible mask is set (masks are disjoint)."""
    out = np.zeros(shape, np.uint16)
    for k, m in enumerate(masks_visib):
        out[m] = k + 1
    return out


def object_coords(view: ViewGeometry, annotations: list, objects) -> tuple[np.ndarray, np.ndarray, np.ndarray,
                                                                         np.ndarray]:
    """Model-frame coordinates of every visible object pixel.

    Returns:
        ``(coords (H, W, 3) metres, valid (H, W) bool, bbox_min (H, W, 3), bbox_size (H, W, 3))``, the last two
        the bbox of each pixel's object (what the file encoding normalizes by).
    """
    H, W = view.depth.shape
    coords = np.zeros((H, W, 3))
    lo = np.zeros((H, W, 3))
    size = np.ones((H, W, 3))
    valid = np.zeros((H, W), bool)
    for ann in annotations:
        m = ann.mask_visib & (view.depth > 0)
        if not m.any():
            continue
        T = ann.T_cam_obj
        coords[m] = (view.points_cam[m] - T.t) @ T.R  # R^T (p - t), row vectors
        obj = objects.get(ann.obj_id)
        lo[m], size[m] = obj.bbox[0], obj.size
        valid |= m
    return coords, valid, lo, size


class MeshTriangles:
    """The triangles of one MuJoCo mesh in its geom's frame, for finding the triangle that contains a surface
    point: candidates are the triangles with the nearest centroids, the choice the one whose plane holds the
    point and whose edges enclose it (a brute-force pass over every triangle for points no candidate holds)."""

    def __init__(self, verts: np.ndarray, faces: np.ndarray) -> None:
        from scipy.spatial import cKDTree

        a, b, c = (verts[faces[:, i]] for i in range(3))
        n = np.cross(b - a, c - a)
        self.normal = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)
        # Each triangle as 4 planes: its own (distance |q.n - a.n|) and, for each edge, the in-plane outward
        # edge normal (q.s - e0.s > 0 outside that edge); the score is the plane distance plus the largest
        # distance outside an edge, 0 for a point in the triangle.
        sides = []
        for e0, e1 in ((a, b), (b, c), (c, a)):
            side = np.cross(e1 - e0, self.normal)
            side /= np.maximum(np.linalg.norm(side, axis=1, keepdims=True), 1e-300)
            sides.append((side, np.einsum("ij,ij->i", e0, side)))
        self.planes = np.stack([self.normal] + [sd for sd, _ in sides], axis=1)  # (M, 4, 3)
        self.offsets = np.stack([np.einsum("ij,ij->i", a, self.normal)] + [o for _, o in sides], axis=1)  # (M, 4)
        self.tree = cKDTree((a + b + c) / 3.0)
        self.k = int(min(8, len(faces)))

    def _score(self, p: np.ndarray, idx: np.ndarray) -> np.ndarray:
        """(N, k) distance of each point from candidate triangles ``idx`` (N, k) (plane distance plus how far
        it lies outside the edges)."""
        d = np.einsum("nj,nkpj->nkp", p, self.planes[idx]) - self.offsets[idx]
        return np.abs(d[..., 0]) + np.maximum(d[..., 1:].max(-1), 0.0)

    def _score_all(self, p: np.ndarray) -> np.ndarray:
        """(N, M) the same against every triangle (matrix products)."""
        d = np.einsum("nj,mpj->nmp", p, self.planes) - self.offsets[None]
        return np.abs(d[..., 0]) + np.maximum(d[..., 1:].max(-1), 0.0)

    def normals_at(self, points: np.ndarray) -> np.ndarray:
        """(N, 3) unit normals (geom frame) of the triangles holding ``points`` (N, 3) (geom frame)."""
        if len(points) == 0:
            return np.zeros((0, 3))
        _, idx = self.tree.query(points, k=self.k)
        idx = idx.reshape(len(points), -1)
        score = self._score(points, idx)
        best = np.argmin(score, axis=1)
        tri = idx[np.arange(len(points)), best]
        far = np.flatnonzero(score[np.arange(len(points)), best] > 1e-4)  # no candidate holds the point
        step = max(1, 1_000_000 // (4 * len(self.normal)))
        for c in range(0, len(far), step):  # those points against every triangle, a chunk at a time
            rows = far[c:c + step]
            tri[rows] = np.argmin(self._score_all(points[rows]), axis=1)
        return self.normal[tri]


def _primitive_normals(gtype: int, size: np.ndarray, p: np.ndarray) -> np.ndarray:
    """(N, 3) unit outward normals (geom frame) of MuJoCo primitive ``gtype`` at surface points ``p``."""
    n = np.zeros_like(p)
    if gtype == 0:  # plane: its z axis
        n[:, 2] = 1.0
    elif gtype == 2:  # sphere
        n = p.copy()
    elif gtype == 3:  # capsule: from the nearest point of the axis segment
        n = p - np.stack([np.zeros(len(p)), np.zeros(len(p)), np.clip(p[:, 2], -size[1], size[1])], axis=1)
    elif gtype == 4:  # ellipsoid: the gradient of sum (x_i / a_i)^2
        n = p / np.maximum(size[:3], 1e-12) ** 2
    elif gtype == 5:  # cylinder: side or cap, whichever surface the point is nearer
        rho = np.hypot(p[:, 0], p[:, 1])
        cap = np.abs(np.abs(p[:, 2]) - size[1]) < np.abs(rho - size[0])
        n[:, 0], n[:, 1] = np.where(cap, 0.0, p[:, 0]), np.where(cap, 0.0, p[:, 1])
        n[:, 2] = np.where(cap, np.sign(p[:, 2]), 0.0)
    elif gtype == 6:  # box: the face the point is nearest
        gap = size[:3][None] - np.abs(p)
        axis = np.argmin(gap, axis=1)
        n[np.arange(len(p)), axis] = np.sign(p[np.arange(len(p)), axis])
    return n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-300)


def surface_normals(view: ViewGeometry, model, meshes: dict[int, MeshTriangles]) -> tuple[np.ndarray, np.ndarray]:
    """Unit normals (H, W, 3) in the OpenCV camera frame and where they are defined (H, W) bool.

    Args:
        view: The view. model: The ``mujoco.MjModel`` that was rendered (geom types, sizes, meshes).
        meshes: Cache of :class:`MeshTriangles` per mesh id, filled here (one scene's model).
    """
    H, W = view.depth.shape
    out = np.zeros((H, W, 3))
    valid = (view.seg >= 0) & (view.depth > 0)
    pts_world = view.points_cam @ view.camera.T_world_cam.R.T + view.camera.T_world_cam.t
    R_cam_world = view.camera.T_cam_world.R
    for g in np.unique(view.seg[valid]):
        m = valid & (view.seg == g)
        R, x = view.geom_xmat[g], view.geom_xpos[g]
        p_local = (pts_world[m] - x) @ R  # R^T (p - x)
        gtype = int(model.geom_type[g])
        if gtype == _MESH:
            mid = int(model.geom_dataid[g])
            if mid not in meshes:
                v0, nv = int(model.mesh_vertadr[mid]), int(model.mesh_vertnum[mid])
                f0, nf = int(model.mesh_faceadr[mid]), int(model.mesh_facenum[mid])
                meshes[mid] = MeshTriangles(np.asarray(model.mesh_vert[v0:v0 + nv], np.float64),
                                            np.asarray(model.mesh_face[f0:f0 + nf], np.int64))
            n_local = meshes[mid].normals_at(p_local)
        else:
            n_local = _primitive_normals(gtype, np.asarray(model.geom_size[g], np.float64), p_local)
        n_cam = n_local @ R.T @ R_cam_world.T  # geom -> world -> camera
        # Two-sided surfaces (planes, open meshes): the normal that faces the camera.
        facing = np.einsum("ij,ij->i", n_cam, view.points_cam[m]) > 0
        n_cam[facing] *= -1.0
        out[m] = n_cam
    return out, valid


def forward_flow(a: ViewGeometry, b: ViewGeometry) -> tuple[np.ndarray, np.ndarray]:
    """Forward flow (H, W, 2) pixels from view ``a`` to view ``b`` and where it is valid (H, W) bool: the point
    each pixel of ``a`` sees, moved with its geom to ``b``'s moment, projected by ``b``'s camera, and seen by
    ``b`` (same geom, depth within :data:`FLOW_DEPTH_TOL`)."""
    H, W = a.depth.shape
    flow = np.zeros((H, W, 2))
    ok = (a.seg >= 0) & (a.depth > 0)
    v, u = np.nonzero(ok)
    g = a.seg[v, u]
    Xw = a.points_cam[v, u] @ a.camera.T_world_cam.R.T + a.camera.T_world_cam.t
    local = np.einsum("nji,nj->ni", a.geom_xmat[g], Xw - a.geom_xpos[g])  # R_a^T (X - x_a)
    Xw_b = np.einsum("nij,nj->ni", b.geom_xmat[g], local) + b.geom_xpos[g]
    Xc_b = Xw_b @ b.camera.T_cam_world.R.T + b.camera.T_cam_world.t
    front = Xc_b[:, 2] > 1e-6
    ub, vb = pinhole_pixels(b.camera.K, np.where(front[:, None], Xc_b, 1.0))
    iu, iv = np.rint(ub).astype(np.int64), np.rint(vb).astype(np.int64)
    inside = front & (iu >= 0) & (iu < b.depth.shape[1]) & (iv >= 0) & (iv < b.depth.shape[0])
    iu_c, iv_c = np.clip(iu, 0, b.depth.shape[1] - 1), np.clip(iv, 0, b.depth.shape[0] - 1)
    seen = inside & (b.seg[iv_c, iu_c] == g) & \
        (np.abs(b.depth[iv_c, iu_c] - Xc_b[:, 2]) <= FLOW_DEPTH_TOL * Xc_b[:, 2])
    flow[v, u, 0], flow[v, u, 1] = ub - u, vb - v
    valid = np.zeros((H, W), bool)
    valid[v[seen], u[seen]] = True
    return np.where(valid[..., None], flow, 0.0), valid


def keypoints_2d(view: ViewGeometry, annotations: list, objects, inst: np.ndarray) -> list[np.ndarray]:
    """Per annotation, (J, 3) ``[u, v, visibility]`` of the object's keypoints (bbox corners, then farthest-
    point surface keypoints): pixels (OpenCV centres), visibility 2 / 1 / 0 (see the module doc)."""
    H, W = view.depth.shape
    out = []
    for k, ann in enumerate(annotations):
        obj = objects.get(ann.obj_id)
        pts = np.concatenate([np.asarray(obj.keypoints_bbox, np.float64), np.asarray(obj.keypoints_fps, np.float64)])
        cam = ann.T_cam_obj.apply(pts)
        z = cam[:, 2]
        u, vv = pinhole_pixels(view.camera.K, np.where(z[:, None] > 1e-6, cam, 1.0))
        iu, iv = np.rint(u).astype(np.int64), np.rint(vv).astype(np.int64)
        inside = (z > 1e-6) & (iu >= 0) & (iu < W) & (iv >= 0) & (iv < H)
        iu_c, iv_c = np.clip(iu, 0, W - 1), np.clip(iv, 0, H - 1)
        seen = inside & (inst[iv_c, iu_c] == k + 1) & (np.abs(view.depth[iv_c, iu_c] - z) <= KEYPOINT_DEPTH_TOL_M)
        vis = np.where(seen, 2, np.where(inside, 1, 0))
        out.append(np.stack([u, vv, vis.astype(np.float64)], axis=1))
    return out


class DenseViews:
    """The dense channels of a scene's views, in view order: each view's instance, coords and normals images
    and keypoints when it is finished, and its flow when the next view is (the last view has none).

    Args:
        channels: The channels asked for (subset of :data:`CHANNELS`).
        model: The scene's ``mujoco.MjModel`` (geom types, sizes, meshes). objects: The object set.
        writer: Deprecated: a :class:`~simtest.io.bop.SceneWriter` the flow images go to directly. Without it
            the caller takes each flow image (:meth:`take_flow`) and hands it to the writer.
    """

    def __init__(self, channels: tuple[str, ...], model, objects, writer=None) -> None:
        self.channels = tuple(channels)
        self.model, self.objects, self.writer = model, objects, writer
        self.meshes: dict[int, MeshTriangles] = {}
        self.previous: tuple[int, ViewGeometry] | None = None
        self._flow: tuple[int, np.ndarray] | None = None
        #: ``{obj_id: (bbox corners, surface keypoints)}`` (the keypoints channel), for the COCO categories.
        self.keypoint_counts: dict[int, tuple[int, int]] | None = None
        if "keypoints" in self.channels:
            self.keypoint_counts = {int(o.obj_id): (len(o.keypoints_bbox), len(o.keypoints_fps)) for o in objects}
        if writer is not None:
            import warnings

            warnings.warn("DenseViews no longer takes the writer: hand take_flow() and keypoint_counts to it",
                          DeprecationWarning, stacklevel=2)
            if self.keypoint_counts is not None:
                writer.keypoint_counts = self.keypoint_counts

    def view(self, im_id: int, frame, camera: CameraModel, state, annotations: list
             ) -> tuple[dict[str, np.ndarray], list[np.ndarray] | None]:
        """``({folder: encoded image}, keypoints or None)`` of one view; the previous view's flow, finished by
        this one, waits in :meth:`take_flow`."""
        from simtest.io import dense as files

        view = view_geometry(camera, frame.depth, frame.seg, state.geom_xpos, state.geom_xmat)
        images: dict[str, np.ndarray] = {}
        inst = instance_map([a.mask_visib for a in annotations], frame.depth.shape)
        if "instances" in self.channels:
            images["instances"] = files.encode_instances(inst)
        if "coords" in self.channels:
            images["coords"] = files.encode_coords(*object_coords(view, annotations, self.objects))
        if "normals" in self.channels:
            images["normals"] = files.encode_normals(*surface_normals(view, self.model, self.meshes))
        if "flow" in self.channels:
            if self.previous is not None:
                prev_id, prev = self.previous
                self._flow = (prev_id, files.encode_flow(*forward_flow(prev, view)))
                if self.writer is not None:
                    self.writer.add_image("flow", *self.take_flow())
            self.previous = (im_id, view)
        kps = keypoints_2d(view, annotations, self.objects, inst) if "keypoints" in self.channels else None
        return images, kps

    def take_flow(self) -> tuple[int, np.ndarray] | None:
        """``(image id, encoded flow image)`` of the view the last :meth:`view` finished, once; else ``None``."""
        flow, self._flow = self._flow, None
        return flow
