"""Watertight mesh primitives for the procedural objects: lathe (body of revolution), swept tube, box, union.

All lengths are metres. Every builder returns a closed, consistently outward-oriented
:class:`trimesh.Trimesh` built from plain numpy arithmetic, so the same inputs give byte-identical vertices.
"""

from __future__ import annotations

import numpy as np
import trimesh

__all__ = ["lathe", "sweep_tube", "box", "union", "from_manifold", "to_manifold", "center_bbox"]


def _oriented(vertices: np.ndarray, faces: np.ndarray) -> trimesh.Trimesh:
    """A mesh from arrays, with faces flipped if needed so that the enclosed volume is positive."""
    mesh = trimesh.Trimesh(vertices=np.ascontiguousarray(vertices, dtype=np.float64),
                           faces=np.ascontiguousarray(faces, dtype=np.int64), process=False)
    if mesh.volume < 0:
        mesh = trimesh.Trimesh(vertices=mesh.vertices, faces=mesh.faces[:, ::-1].copy(), process=False)
    return mesh


def _ring_faces(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Two triangles per quad between two closed vertex rings ``a`` and ``b`` of equal length."""
    a1 = np.roll(a, -1)
    b1 = np.roll(b, -1)
    return np.concatenate([np.stack([a, a1, b1], axis=1), np.stack([a, b1, b], axis=1)])


def _fan(pole: int, ring: np.ndarray) -> np.ndarray:
    return np.stack([np.full_like(ring, pole), np.roll(ring, -1), ring], axis=1)


def lathe(profile: np.ndarray, segments: int = 48) -> trimesh.Trimesh:
    """Revolve a profile about the z axis into a closed solid.

    Args:
        profile: (M, 2) points ``(r, z)`` in metres, M >= 3. The first and last points must lie on the axis
            (``r == 0``); they become single pole vertices. The others must have ``r > 0``. The polyline
            must not cross itself; going from the first to the last point it may fold back (e.g. the outer
            wall up and the inner wall down for a vessel).
        segments: Vertices per ring. A multiple of 4 keeps the axis-aligned bbox centred on the axis.

    Returns:
        A watertight mesh with ``2 + (M - 2) * segments`` vertices.
    """
    profile = np.asarray(profile, dtype=np.float64)
    if profile.ndim != 2 or profile.shape[1] != 2 or len(profile) < 3:
        raise ValueError(f"profile must be (M >= 3, 2), got shape {profile.shape}")
    if profile[0, 0] != 0 or profile[-1, 0] != 0 or np.any(profile[1:-1, 0] <= 0):
        raise ValueError("profile must start and end on the axis (r == 0) with r > 0 in between")
    if segments < 3:
        raise ValueError(f"segments must be >= 3, got {segments}")
    ang = 2.0 * np.pi * np.arange(segments) / segments
    cos, sin = np.cos(ang), np.sin(ang)
    inner = profile[1:-1]
    rings = np.stack([inner[:, :1] * cos, inner[:, :1] * sin, np.repeat(inner[:, 1:2], segments, axis=1)],
                     axis=-1).reshape(-1, 3)
    verts = np.concatenate([[[0.0, 0.0, profile[0, 1]]], rings, [[0.0, 0.0, profile[-1, 1]]]])
    n_rings = len(inner)
    idx = 1 + np.arange(n_rings * segments).reshape(n_rings, segments)
    faces = [_fan(0, idx[0])]
    for i in range(n_rings - 1):
        faces.append(_ring_faces(idx[i], idx[i + 1]))
    faces.append(_fan(len(verts) - 1, idx[-1])[:, ::-1])
    return _oriented(verts, np.concatenate(faces))


def sweep_tube(centers: np.ndarray, normals: np.ndarray, binormals: np.ndarray, radius_n: np.ndarray,
               radius_b: np.ndarray, sides: int = 16, caps: np.ndarray | None = None,
               shape_fn=None) -> trimesh.Trimesh:
    """Sweep an elliptical cross-section along a path into a closed tube.

    Args:
        centers: (M, 3) path points, metres.
        normals: (M, 3) unit vectors normal to the path (first cross-section axis).
        binormals: (M, 3) unit vectors normal to the path and to ``normals`` (second axis).
        radius_n: (M,) half-width along ``normals``, metres (> 0).
        radius_b: (M,) half-width along ``binormals``, metres (> 0).
        sides: Vertices per cross-section.
        caps: (2, 3) positions of the two end-cap apex vertices (default: the first and last centres, i.e.
            flat caps). Points beyond the ends round the tube off.
        shape_fn: Optional ``f(phi) -> (sides,)`` radial factor applied to every cross-section (e.g. ridges).

    Returns:
        A watertight mesh.
    """
    centers = np.asarray(centers, dtype=np.float64)
    m = len(centers)
    phi = 2.0 * np.pi * np.arange(sides) / sides
    factor = np.ones(sides) if shape_fn is None else np.asarray(shape_fn(phi), dtype=np.float64)
    c = (np.cos(phi) * factor)[None, :, None]
    s = (np.sin(phi) * factor)[None, :, None]
    rn = np.asarray(radius_n, dtype=np.float64)[:, None, None]
    rb = np.asarray(radius_b, dtype=np.float64)[:, None, None]
    rings = centers[:, None, :] + rn * c * np.asarray(normals)[:, None, :] + rb * s * np.asarray(binormals)[:, None, :]
    if caps is None:
        caps = np.stack([centers[0], centers[-1]])
    verts = np.concatenate([caps[:1], rings.reshape(-1, 3), caps[1:]])
    idx = 1 + np.arange(m * sides).reshape(m, sides)
    faces = [_fan(0, idx[0])]
    for i in range(m - 1):
        faces.append(_ring_faces(idx[i], idx[i + 1]))
    faces.append(_fan(len(verts) - 1, idx[-1])[:, ::-1])
    return _oriented(verts, np.concatenate(faces))


def box(size: np.ndarray, subdivisions: int = 0) -> trimesh.Trimesh:
    """A closed axis-aligned box of ``size`` (3,) metres centred at the origin.

    Args:
        size: Edge lengths (x, y, z), metres.
        subdivisions: Times every triangle is split in four (0: 12 triangles).
    """
    mesh = trimesh.creation.box(extents=np.asarray(size, dtype=np.float64))
    for _ in range(subdivisions):
        mesh = mesh.subdivide()
    return trimesh.Trimesh(vertices=np.asarray(mesh.vertices), faces=np.asarray(mesh.faces), process=False)


def to_manifold(mesh: trimesh.Trimesh):
    """A ``manifold3d.Manifold`` from a watertight mesh (float32 precision, as manifold3d stores it)."""
    import manifold3d

    m = manifold3d.Manifold(manifold3d.Mesh(
        vert_properties=np.ascontiguousarray(mesh.vertices, dtype=np.float32),
        tri_verts=np.ascontiguousarray(mesh.faces, dtype=np.uint32)))
    if m.status().name != "NoError":
        raise ValueError(f"mesh is not a valid manifold: {m.status().name}")
    return m


def from_manifold(manifold) -> trimesh.Trimesh:
    """A trimesh from a ``manifold3d.Manifold`` (vertices as float64)."""
    out = manifold.to_mesh()
    verts = np.asarray(out.vert_properties, dtype=np.float64)[:, :3]
    faces = np.asarray(out.tri_verts, dtype=np.int64)
    return _oriented(verts, faces)


def union(*meshes) -> trimesh.Trimesh:
    """Exact boolean union (manifold3d) of watertight meshes or ``manifold3d.Manifold`` objects."""
    import manifold3d

    parts = [m if isinstance(m, manifold3d.Manifold) else to_manifold(m) for m in meshes]
    result = manifold3d.Manifold.batch_boolean(parts, manifold3d.OpType.Add)
    return from_manifold(result)


def center_bbox(mesh: trimesh.Trimesh) -> tuple[trimesh.Trimesh, np.ndarray]:
    """Translate a mesh so its axis-aligned bbox centre is at the origin.

    Returns:
        The centred mesh and the subtracted bbox centre (3,), metres.
    """
    bounds = np.asarray(mesh.bounds, dtype=np.float64)
    center = 0.5 * (bounds[0] + bounds[1])
    verts = np.asarray(mesh.vertices, dtype=np.float64) - center
    return trimesh.Trimesh(vertices=verts, faces=np.asarray(mesh.faces), process=False), center
