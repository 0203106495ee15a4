"""Collision geometry for MuJoCo: convex hulls, or a CoACD convex decomposition cached by mesh hash."""

from __future__ import annotations

import io
import logging
import time
from typing import TYPE_CHECKING

import numpy as np
import trimesh

from simtest.io.files import atomic_write_bytes

if TYPE_CHECKING:
    from simtest.objects.model import ObjectModel

__all__ = ["convex_parts"]

log = logging.getLogger(__name__)

#: CoACD concavity threshold; 0.04 keeps mug handles and bowl walls open with at most 24 parts.
#: Measured on the built-in vessels (one core): mug 4 s, cup 4 s, bowl 6 s, banana 0.3 s, drill 0.8 s; the
#: parts stick out of the mesh by < 3.5 mm for 95 % of their volume (bowl), < 1 mm (mug).
COACD_THRESHOLD = 0.04
#: Upper bound on the number of convex parts per object.
COACD_MAX_PARTS = 24
#: Bump when the decomposition parameters change, so stale cache entries are not reused.
_CACHE_VERSION = 2


def convex_parts(obj: "ObjectModel") -> tuple[trimesh.Trimesh, ...]:
    """Convex pieces (model frame, metres) whose union approximates ``obj.mesh`` for collision."""
    if not obj.is_concave:
        return (obj.mesh.convex_hull,)
    from simtest.objects.model import cache_dir

    path = cache_dir() / "coacd" / f"{obj.mesh_hash}_v{_CACHE_VERSION}_{COACD_THRESHOLD}.npz"
    if path.exists():
        try:
            with np.load(path) as data:
                n = int(data["n"])
                return tuple(trimesh.Trimesh(data[f"v{i}"], data[f"f{i}"], process=False) for i in range(n))
        except Exception as exc:  # a corrupt cache entry is recomputed, never trusted
            log.warning("ignoring unreadable collision cache %s: %s", path, exc)
    parts = _decompose(obj.mesh)
    buf = io.BytesIO()
    arrays = {"n": np.array(len(parts))}
    for i, p in enumerate(parts):
        arrays[f"v{i}"] = np.asarray(p.vertices)
        arrays[f"f{i}"] = np.asarray(p.faces)
    np.savez(buf, **arrays)
    atomic_write_bytes(path, buf.getvalue())
    return parts


def _decompose(mesh: trimesh.Trimesh) -> tuple[trimesh.Trimesh, ...]:
    import coacd

    coacd.set_log_level("error")
    cm = coacd.Mesh(np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int64))
    # A watertight mesh is already a valid manifold: skip the remeshing pre-pass (faster, exact input).
    mode = "off" if mesh.is_watertight else "on"
    start = time.perf_counter()
    result = coacd.run_coacd(cm, threshold=COACD_THRESHOLD, max_convex_hull=COACD_MAX_PARTS, seed=0,
                             preprocess_mode=mode, preprocess_resolution=40, resolution=1000,
                             mcts_iterations=60, mcts_max_depth=2)
    log.info("CoACD: %d parts in %.2f s", len(result), time.perf_counter() - start)
    parts = []
    for v, f in result:
        part = trimesh.Trimesh(np.asarray(v), np.asarray(f), process=True).convex_hull
        if part.volume > 1e-9:
            parts.append(part)
    if not parts:
        parts = [mesh.convex_hull]
    return tuple(parts)
