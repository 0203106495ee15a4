"""Exact amodal silhouettes of triangle meshes, without OpenGL: the pixel-centre rule of the GL rasterizer.

The annotator's amodal masks (:mod:`simtest.generators.annotate`) and the silhouette fit of the RGB-only
estimators (:mod:`simtest.estimators.silhouette`) share this code, so a refined pose is scored against the same
outline the ground truth was made with.

Conventions: camera frame OpenCV (x right, y down, z forward), metres; pixel ``(row y, col x)`` samples the image
point ``(x, y)`` (pixel centres at integers, as :mod:`simtest.render.zbuffer`).
"""

from __future__ import annotations

import weakref

import numpy as np

from simtest.camera import pinhole_pixels

__all__ = ["rasterize_silhouette", "EdgeTopology", "edge_topology", "fill_faces", "front_faces",
           "object_silhouette"]


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
    return fill_faces(uv, tris, topology, np.arange(len(tris)), np.ones(len(tris), dtype=np.int64))


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


def fill_faces(uv: np.ndarray, faces: np.ndarray, topology: EdgeTopology, sel: np.ndarray, orient: np.ndarray
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


def front_faces(obj, uv: np.ndarray, z: np.ndarray, near: float) -> tuple[np.ndarray, np.ndarray]:
    """``(faces, orientation)`` to fill for ``obj``'s silhouette from projected vertices ``uv`` (N, 2) pixels at
    depths ``z`` (N,) metres: for a closed mesh its front faces (positive 2D orientation; their union is the
    silhouette), for an open mesh every face, each turned (-1) to the same orientation. Faces with a vertex at
    ``z <= near`` are dropped."""
    faces = obj.faces
    pa, pb, pc = uv[faces[:, 0]], uv[faces[:, 1]], uv[faces[:, 2]]
    area2 = (pb[:, 0] - pa[:, 0]) * (pc[:, 1] - pa[:, 1]) - (pb[:, 1] - pa[:, 1]) * (pc[:, 0] - pa[:, 0])
    in_front = np.all(z[faces] > near, axis=1)
    if obj.is_watertight:
        sel = np.flatnonzero(in_front & (area2 > 0))
        return sel, np.ones(len(sel), dtype=np.int64)
    sel = np.flatnonzero(in_front & (area2 != 0))
    return sel, np.where(area2[sel] > 0, 1, -1)


def object_silhouette(obj, R: np.ndarray, t: np.ndarray, K: np.ndarray, width: int, height: int,
                      near: float = 0.01) -> np.ndarray:
    """(height, width) bool: the amodal silhouette of ``obj`` (mesh in metres) at pose ``R``, ``t`` (model to
    camera, metres) through intrinsics ``K`` (pixels), clipped to the image."""
    X = obj.vertices @ np.asarray(R, np.float64).T + np.asarray(t, np.float64).reshape(3)
    z = X[:, 2]
    u, v = pinhole_pixels(np.asarray(K, np.float64), X, np.maximum(z, near))  # faces behind `near` are dropped
    uv = np.stack([u, v], axis=1)
    sel, orient = front_faces(obj, uv, z, near)
    out = np.zeros((int(height), int(width)), bool)
    sil, (x0, y0) = fill_faces(uv, obj.faces, edge_topology(obj), sel, orient)
    if sil.size == 0:
        return out
    ya, xa = max(y0, 0), max(x0, 0)
    yb, xb = min(y0 + sil.shape[0], out.shape[0]), min(x0 + sil.shape[1], out.shape[1])
    if ya < yb and xa < xb:
        out[ya:yb, xa:xb] = sil[ya - y0:yb - y0, xa - x0:xb - x0]
    return out
