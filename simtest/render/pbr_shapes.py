"""Shapes for the path tracer: Mitsuba transforms and triangle meshes from arrays, and the tessellations of
MuJoCo primitives it draws as meshes (boxes and planes with MuJoCo's 2D texture coordinates, ellipsoids).
Lengths in metres, world frame."""

from __future__ import annotations

import numpy as np

__all__ = ["transform", "mesh_from_arrays", "box_arrays", "sphere_arrays"]


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
