"""Geometry checks shared by the object tests."""

from __future__ import annotations


def surface_distance(mesh, points):
    """Distance (m) from each point to the mesh surface.

    Points whose projection falls inside a triangle get the exact plane distance (trimesh's closest-point
    query can report a few micrometres for points right next to an edge); the others use trimesh.
    """
    import numpy as np
    import trimesh

    points = np.asarray(points, dtype=np.float64)
    _, dist, _ = trimesh.proximity.closest_point(mesh, points)
    tri = np.asarray(mesh.triangles)
    normals = np.asarray(mesh.face_normals)
    for i, p in enumerate(points):
        plane = np.einsum("ij,ij->i", tri[:, 0] - p, normals)
        near = np.flatnonzero(np.abs(plane) <= dist[i] + 1e-12)
        if len(near) == 0:
            continue
        proj = p + plane[near, None] * normals[near]
        bary = trimesh.triangles.points_to_barycentric(tri[near], proj)
        inside = np.all(bary >= -1e-9, axis=1)
        if inside.any():
            dist[i] = min(dist[i], float(np.abs(plane[near][inside]).min()))
    return dist
