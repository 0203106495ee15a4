"""Collision geometry for MuJoCo: convex hulls, or a CoACD convex decomposition cached by mesh hash.

Meshes that are not watertight (an open-topped shell, a handle modelled as an open tube) have no inside, so
their concavity is judged on the solid their surface encloses: the surface is voxelised, the voxels it
closes off are filled, and the mesh counts as concave when its convex hull is more than
:data:`OPEN_CONCAVITY_RATIO` times that solid. Such a mesh is decomposed from CoACD's manifold remesh of it
(``preprocess_mode="on"``) with the cheaper :data:`OPEN_MESH_SETTINGS`, as thin shells need many cuts.
"""

from __future__ import annotations

import io
import logging
import time
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import trimesh
from scipy import ndimage

from simtest.io.files import atomic_write_bytes

if TYPE_CHECKING:
    from simtest.objects.model import ObjectModel

__all__ = ["convex_parts", "decomposition_cache_path", "enclosed_volume", "open_mesh_is_concave", "open_mesh_note"]

log = logging.getLogger(__name__)

#: CoACD concavity threshold; 0.04 keeps mug handles and bowl walls open with at most 24 parts.
#: Measured on the built-in vessels (one core): mug 4 s, cup 4 s, bowl 6 s, banana 0.3 s, drill 0.8 s; the
#: parts stick out of the mesh by < 3.5 mm for 95 % of their volume (bowl), < 1 mm (mug).
COACD_THRESHOLD = 0.04
#: Upper bound on the number of convex parts per object.
COACD_MAX_PARTS = 24
#: Bump when the decomposition parameters change, so stale cache entries are not reused.
_CACHE_VERSION = 2
#: Bump when :data:`OPEN_MESH_SETTINGS` change (cache entries of meshes that are not watertight).
_OPEN_CACHE_VERSION = 1
#: CoACD settings for meshes that are not watertight (their manifold remesh is a thin shell that needs many
#: cuts): on the open-handled test mug about 15 s of one core, parts stick out < 4 mm for 95 % of their volume.
OPEN_MESH_SETTINGS = dict(preprocess_mode="on", preprocess_resolution=30, resolution=500, mcts_iterations=20,
                          mcts_max_depth=2, max_convex_hull=16)
#: Settings for watertight meshes (exact input, no remesh).
WATERTIGHT_SETTINGS = dict(preprocess_mode="off", preprocess_resolution=40, resolution=1000, mcts_iterations=60,
                           mcts_max_depth=2, max_convex_hull=COACD_MAX_PARTS)
#: An open mesh is concave when its hull exceeds the solid its surface encloses by this factor.
OPEN_CONCAVITY_RATIO = 1.1
#: Voxels across the bounding-box diagonal when filling an open surface.
FILL_RESOLUTION = 64


def decomposition_cache_path(obj: "ObjectModel") -> Path | None:
    """Where the CoACD parts of ``obj`` are cached (by mesh hash, under :func:`~simtest.objects.cache.cache_dir`),
    or ``None`` for a convex object (its hull needs no decomposition)."""
    if not obj.is_concave:
        return None
    from simtest.objects.cache import cache_dir

    tag = "" if obj.mesh.is_watertight else f"_open{_OPEN_CACHE_VERSION}"
    return cache_dir() / "coacd" / f"{obj.mesh_hash}_v{_CACHE_VERSION}_{COACD_THRESHOLD}{tag}.npz"


def convex_parts(obj: "ObjectModel") -> tuple[trimesh.Trimesh, ...]:
    """Convex pieces (model frame, metres) whose union approximates ``obj.mesh`` for collision."""
    path = decomposition_cache_path(obj)
    if path is None:
        return (obj.mesh.convex_hull,)
    if path.exists():
        try:
            with np.load(path) as data:
                n = int(data["n"])
                return tuple(trimesh.Trimesh(data[f"v{i}"], data[f"f{i}"], process=False) for i in range(n))
        except Exception as exc:  # a corrupt cache entry is recomputed, never trusted
            log.warning("ignoring unreadable collision cache %s: %s", path, exc)
    _say_why_computed(obj)
    parts = _decompose(obj.mesh)
    buf = io.BytesIO()
    arrays = {"n": np.array(len(parts))}
    for i, p in enumerate(parts):
        arrays[f"v{i}"] = np.asarray(p.vertices)
        arrays[f"f{i}"] = np.asarray(p.faces)
    np.savez(buf, **arrays)
    atomic_write_bytes(path, buf.getvalue())
    return parts


def collision_key(obj: "ObjectModel") -> dict:
    """The fields the collision cache entry of ``obj`` depends on: its units and scale (which change the mesh),
    the decomposition's version and threshold, the settings for open meshes, and the mesh hash itself."""
    return {"units": obj.extra.get("units"), "scale": obj.extra.get("scale"), "version": _CACHE_VERSION,
            "threshold": COACD_THRESHOLD,
            "open mesh settings": None if obj.mesh.is_watertight else _OPEN_CACHE_VERSION, "mesh": obj.mesh_hash}


def _say_why_computed(obj: "ObjectModel") -> None:
    """Log one line when a decomposition this source had in the cache is computed again for a changed key."""
    from simtest.objects.cache import key_change

    why = key_change("coacd", obj.source, collision_key(obj))
    if why:
        log.warning("%s: collision parts computed again: the cache key changed (%s)", obj.source or obj.name, why)


def _decompose(mesh: trimesh.Trimesh) -> tuple[trimesh.Trimesh, ...]:
    import coacd

    coacd.set_log_level("error")
    cm = coacd.Mesh(np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64))
    # A watertight mesh is already a valid manifold: skip the remeshing pre-pass (faster, exact input).
    settings = WATERTIGHT_SETTINGS if mesh.is_watertight else OPEN_MESH_SETTINGS
    start = time.perf_counter()
    result = coacd.run_coacd(cm, threshold=COACD_THRESHOLD, seed=0, **settings)
    log.info("CoACD (%s): %d parts in %.2f s", "watertight" if mesh.is_watertight else "manifold remesh",
             len(result), time.perf_counter() - start)
    parts = []
    for v, f in result:
        part = trimesh.Trimesh(np.asarray(v), np.asarray(f), process=True).convex_hull
        if part.volume > 1e-9:
            parts.append(part)
    if not parts:
        parts = [mesh.convex_hull]
    return tuple(parts)


def _filled_voxels(mesh: trimesh.Trimesh, resolution: int = FILL_RESOLUTION) -> tuple[np.ndarray, float]:
    """Voxels (boolean grid) of the solid a surface encloses, and the voxel size (metres).

    The surface is sampled densely (8 samples per voxel face area) into a grid, thickened by one voxel so
    sampling gaps close, filled where enclosed, and thinned again.
    """
    pitch = float(np.linalg.norm(np.ptp(np.asarray(mesh.vertices), axis=0))) / resolution
    n = int(min(400_000, 8 * float(mesh.area) / pitch ** 2))
    pts, _ = trimesh.sample.sample_surface(mesh, max(n, 1000), seed=np.random.default_rng(0))
    pts = np.concatenate([pts, np.asarray(mesh.vertices)])
    idx = np.floor((pts - (mesh.bounds[0] - 2.5 * pitch)) / pitch).astype(np.int64)
    grid = np.zeros(idx.max(axis=0) + 4, dtype=bool)
    grid[tuple(idx.T)] = True
    cube = np.ones((3, 3, 3), dtype=bool)
    closed = ndimage.binary_fill_holes(ndimage.binary_dilation(grid, structure=cube))
    return ndimage.binary_erosion(closed, structure=cube) | grid, pitch


def enclosed_volume(mesh: trimesh.Trimesh) -> float:
    """Volume (m^3) of the solid a possibly open surface encloses, by voxel filling (a thin shell counts
    about one voxel thick; :data:`FILL_RESOLUTION` voxels across the diagonal)."""
    filled, pitch = _filled_voxels(mesh)
    return float(filled.sum()) * pitch ** 3


def open_mesh_is_concave(mesh: trimesh.Trimesh) -> bool:
    """Whether a mesh that is not watertight needs a convex decomposition (see the module docstring)."""
    return bool(mesh.convex_hull.volume > OPEN_CONCAVITY_RATIO * enclosed_volume(mesh))


def open_mesh_note(obj: "ObjectModel") -> str:
    """What simtest does with a mesh that is not watertight, for the loader's warning."""
    edges = trimesh.grouping.group_rows(obj.mesh.edges_sorted, require_count=1)
    what = ("collision uses a convex decomposition of a watertight remesh (CoACD manifold preprocessing, "
            "computed on first use and cached)" if obj.is_concave else "collision uses its convex hull (it is "
            "nearly convex)")
    return (f"mesh is not watertight ({len(edges)} open edges); mass and inertia use its convex hull; {what}; "
            "grasp candidates that would put the open gripper inside the collision geometry are dropped")
