"""Shapes for the path tracer: Mitsuba transforms and triangle meshes from arrays, and the tessellations of
MuJoCo primitives it draws as meshes (boxes and planes with MuJoCo's 2D texture coordinates, ellipsoids).
Lengths in metres, world frame."""

from __future__ import annotations

import numpy as np

import simtest  # noqa: F401  (GL backend before mujoco)
import mujoco

__all__ = ["transform", "mesh_from_arrays", "box_arrays", "sphere_arrays", "geom_shapes", "mesh_geom",
           "INFINITE_PLANE"]

#: Half size of a MuJoCo plane whose size is 0 ("infinite"), metres.
INFINITE_PLANE = 50.0
_G = mujoco.mjtGeom


def transform(mi, R: np.ndarray, t: np.ndarray, scale: np.ndarray | None = None):
    """Mitsuba 4x4 transform ``[R diag(scale) | t]``."""
    M = np.eye(4)
    M[:3, :3] = R if scale is None else R @ np.diag(scale)
    M[:3, 3] = t
    return mi.ScalarTransform4f(M.tolist())


def mesh_from_arrays(mi, name: str, verts: np.ndarray, faces: np.ndarray, normals: np.ndarray | None = None,
          uv: np.ndarray | None = None):
    """A Mitsuba triangle mesh from arrays (world coordinates)."""
    mesh = mi.Mesh(name, len(verts), len(faces), has_vertex_normals=normals is not None,
                   has_vertex_texcoords=uv is not None)
    params = mi.traverse(mesh)
    params["vertex_positions"] = np.ascontiguousarray(verts, dtype=np.float32).ravel()
    params["faces"] = np.ascontiguousarray(faces, dtype=np.uint32).ravel()
    if normals is not None:
        params["vertex_normals"] = np.ascontiguousarray(normals, dtype=np.float32).ravel()
    if uv is not None:
        params["vertex_texcoords"] = np.ascontiguousarray(uv, dtype=np.float32).ravel()
    params.update()
    return mesh


def box_arrays(half: np.ndarray, repeat: np.ndarray, top_only: bool = False):
    """Vertices, faces, normals and uv of a box with half sizes ``half`` (metres); ``top_only``: its +z face
    alone (a plane). Each face carries the texture ``repeat`` times across it (MuJoCo's 2D mapping with
    ``texuniform`` off)."""
    sides = [(2, 1.0)] if top_only else [(a, s) for a in range(3) for s in (1.0, -1.0)]
    verts, faces, normals, uvs = [], [], [], []
    for n_ax, sign in sides:
        # (u, v, n) right-handed, so the corners below run counter-clockwise seen from outside.
        u_ax, v_ax = ((n_ax + 1) % 3, (n_ax + 2) % 3) if sign > 0 else ((n_ax + 2) % 3, (n_ax + 1) % 3)
        base = len(verts)
        for su, sv in ((-1, -1), (1, -1), (1, 1), (-1, 1)):
            p = np.zeros(3)
            p[n_ax], p[u_ax], p[v_ax] = sign * half[n_ax], su * half[u_ax], sv * half[v_ax]
            verts.append(p)
            normals.append(np.eye(3)[n_ax] * sign)
            uvs.append([(su + 1) / 2 * repeat[0], (sv + 1) / 2 * repeat[1]])
        faces += [[base, base + 1, base + 2], [base, base + 2, base + 3]]
    return np.array(verts), np.array(faces), np.array(normals), np.array(uvs)


def sphere_arrays(n_lat: int = 24, n_lon: int = 48) -> tuple[np.ndarray, np.ndarray]:
    """Unit sphere: vertices (= normals) and faces of a latitude-longitude tessellation."""
    th = np.linspace(0.0, np.pi, n_lat + 1)
    ph = np.linspace(0.0, 2 * np.pi, n_lon + 1)
    T, P = np.meshgrid(th, ph, indexing="ij")
    verts = np.stack([np.sin(T) * np.cos(P), np.sin(T) * np.sin(P), np.cos(T)], axis=-1).reshape(-1, 3)
    idx = np.arange((n_lat + 1) * (n_lon + 1)).reshape(n_lat + 1, n_lon + 1)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    faces = np.concatenate([np.stack([a, b, c], -1).reshape(-1, 3), np.stack([a, c, d], -1).reshape(-1, 3)])
    return verts, faces


def geom_shapes(mi, m: mujoco.MjModel, data: mujoco.MjData, g: int, bsdf) -> list:
    """Mitsuba shapes (dicts or meshes with ``bsdf``) of geom ``g`` of model ``m`` at its world pose in ``data``;
    heightfields, SDFs and lines give none."""
    R, t = data.geom_xmat[g].reshape(3, 3).astype(np.float64), data.geom_xpos[g].astype(np.float64)
    size, gtype = m.geom_size[g].astype(np.float64), int(m.geom_type[g])
    name = f"geom_{g}"
    if gtype == _G.mjGEOM_MESH:
        return [mesh_geom(mi, m, int(m.geom_dataid[g]), R, t, name, bsdf)]
    if gtype in (_G.mjGEOM_BOX, _G.mjGEOM_PLANE):
        mat = int(m.geom_matid[g])
        repeat = m.mat_texrepeat[mat].astype(np.float64) if mat >= 0 else np.ones(2)
        half = size.copy()
        if gtype == _G.mjGEOM_PLANE:  # its surface is z = 0 of its frame; size[2] is the grid spacing
            half[:2] = np.where(half[:2] > 0, half[:2], INFINITE_PLANE)
            half[2] = 0.0
        v, f, n, uv = box_arrays(half, repeat, top_only=gtype == _G.mjGEOM_PLANE)
        return [_with_bsdf(mesh_from_arrays(mi, name, v @ R.T + t, f, n @ R.T, uv), bsdf)]
    if gtype == _G.mjGEOM_SPHERE:
        return [{"type": "sphere", "center": t.tolist(), "radius": float(size[0]), "bsdf": bsdf}]
    if gtype == _G.mjGEOM_ELLIPSOID:
        v, f = sphere_arrays()
        n = v / size
        n /= np.linalg.norm(n, axis=1, keepdims=True)
        return [_with_bsdf(mesh_from_arrays(mi, name, (v * size) @ R.T + t, f, n @ R.T), bsdf)]
    if gtype in (_G.mjGEOM_CYLINDER, _G.mjGEOM_CAPSULE):
        r, hh = float(size[0]), float(size[1])
        shapes = [{"type": "cylinder", "p0": [0.0, 0.0, -hh], "p1": [0.0, 0.0, hh], "radius": r,
                   "to_world": transform(mi, R, t), "bsdf": bsdf}]
        for s in (1.0, -1.0):
            end = t + s * hh * R[:, 2]
            if gtype == _G.mjGEOM_CAPSULE:
                shapes.append({"type": "sphere", "center": end.tolist(), "radius": r, "bsdf": bsdf})
            else:  # a cap disk facing outward
                Rc = R if s > 0 else R @ np.diag([1.0, -1.0, -1.0])
                shapes.append({"type": "disk", "to_world": transform(mi, Rc, end, np.array([r, r, 1.0])),
                               "bsdf": bsdf})
        return shapes
    return []  # heightfields, SDFs, lines: not drawn by the path tracer

def _with_bsdf(mesh, bsdf):
    mesh.set_bsdf(bsdf)
    return mesh

def mesh_geom(mi, m: mujoco.MjModel, mesh_id: int, R: np.ndarray, t: np.ndarray, name: str, bsdf):
    """Mesh ``mesh_id`` of model ``m`` in the world (rotation ``R``, translation ``t``, metres), with MuJoCo's
    per-corner normals and texture coordinates (unshared corners)."""
    va, fa, na = int(m.mesh_vertadr[mesh_id]), int(m.mesh_faceadr[mesh_id]), int(m.mesh_normaladr[mesh_id])
    fn = int(m.mesh_facenum[mesh_id])
    verts = m.mesh_vert[va:va + int(m.mesh_vertnum[mesh_id])].astype(np.float64)
    normals = m.mesh_normal[na:na + int(m.mesh_normalnum[mesh_id])].astype(np.float64)
    faces = m.mesh_face[fa:fa + fn]
    corner_v = verts[faces].reshape(-1, 3) @ R.T + t
    corner_n = normals[m.mesh_facenormal[fa:fa + fn]].reshape(-1, 3) @ R.T
    tris = np.arange(3 * fn, dtype=np.uint32).reshape(-1, 3)
    uv = None
    if int(m.mesh_texcoordnum[mesh_id]) > 0:
        ta = int(m.mesh_texcoordadr[mesh_id])
        texcoords = m.mesh_texcoord[ta:ta + int(m.mesh_texcoordnum[mesh_id])].astype(np.float64)
        uv = texcoords[m.mesh_facetexcoord[fa:fa + fn]].reshape(-1, 2)  # same (u, v) convention as Mitsuba
    return _with_bsdf(mesh_from_arrays(mi, name, corner_v, tris, corner_n, uv), bsdf)
