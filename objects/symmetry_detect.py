"""Detect the rotational symmetries of a mesh that declares none, in the BOP form of :mod:`.symmetry`.

A candidate rotation is a symmetry when it maps the surface onto itself: points sampled area-uniformly on
the surface (so the result does not depend on how the mesh is tessellated) are moved by the rotation, and
each must lie within ``tol * diameter`` of the surface (the distance to the nearest of a dense reference
sample, measured to its tangent plane, and never less than the plain distance minus the sample spacing).
Mapping the surface *into* itself is enough: a rigid motion of a surface into itself preserves its area,
so it maps the surface *onto* itself.

Every rotational symmetry fixes the surface centroid and permutes the principal axes of the surface's
second moment, so the candidate axes pass through the centroid: the model's x, y and z axes (most meshes
are modelled axis-aligned), the principal axes, and for an axis with a 3-fold or higher symmetry the
perpendicular directions towards the farthest surface point (the flip axes of a prism). On each axis a
continuous symmetry is tried first (several unrelated angles), else the 2, 3, 4, 5 and 6-fold rotations.
The discrete rotations found generate a group, whose elements are all checked and returned.

Symmetry in BOP's sense is *visual* indistinguishability, so for an object with colours (a texture, colours per
vertex or per face: :class:`~simtest.objects.appearance.Appearance`) a rotation must also map the colours: the
colour of each moved probe is compared with the colour of the nearest reference point, and the rotation is
refused when more than :data:`COLOR_MISMATCH` of the probes differ by more than :data:`COLOR_TOLERANCE` in any
channel (a die's faces are told apart by their pips; a uniformly coloured cube keeps its 24 rotations). The
share allows for probes near a colour edge, whose nearest reference point may lie across it. ``symmetry=
"geometry"`` detects by shape alone.

Results are cached in-process per mesh hash and tolerance, and on disk (``<cache_dir>/symmetry/``, next to the
collision cache of :mod:`simtest.objects.collision`), so a mesh library's objects are examined once, when a
scene first uses them.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import logging
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import trimesh
from scipy.spatial import cKDTree
from trimesh.triangles import points_to_barycentric

from simtest.errors import ConfigError
from simtest.geometry import rotation_about
from simtest.io.files import atomic_write_json
from simtest.objects.appearance import Appearance, surface_colors
from simtest.objects.model import ContinuousSymmetry, ObjectModel, ObjectSet

if TYPE_CHECKING:
    from collections.abc import Sequence

__all__ = ["detect_symmetries", "apply_symmetry_policy", "with_symmetry_policy", "symmetry_status", "uses_colors",
           "SYMMETRY_POLICIES", "DEFAULT_TOLERANCE", "COLOR_TOLERANCE", "COLOR_MISMATCH", "symmetry_cache_path"]

#: ``auto``: objects without declared symmetries get the detected ones (by shape and, when the object has
#: colours, by colours too); ``geometry``: detected by shape alone; ``none``: no detection.
SYMMETRY_POLICIES = ("auto", "geometry", "none")
#: Largest colour difference (any channel, colours in [0, 1]) of a probe that still counts as the same colour.
COLOR_TOLERANCE = 0.2
#: Largest share of probes whose colours may differ (colour edges) under a symmetry.
COLOR_MISMATCH = 0.02
#: Largest surface deviation of a symmetry, as a fraction of the object diameter.
DEFAULT_TOLERANCE = 0.01
log = logging.getLogger(__name__)

#: Angles (radians) tried for a continuous symmetry: unrelated to each other, so that no discrete n-fold
#: symmetry (n <= 12) passes them all.
_CONTINUOUS_ANGLES = (1.37, 0.41, 2.29, 3.61, 5.03)
#: n of the discrete rotations tried about each axis.
_FOLDS = (2, 3, 4, 5, 6)
#: Surface samples moved by each candidate, and the reference sample they are compared with.
_NUM_PROBES = 1500
_NUM_REFERENCE = 100_000
#: Reference neighbours of a moved probe; the nearest tangent plane among them counts (robust at edges).
_NEIGHBOURS = 6
#: Most elements of a detected discrete group (the icosahedral group has 60).
_MAX_GROUP = 60

_CACHE: dict[tuple[str, float], tuple[tuple[np.ndarray, ...], tuple[ContinuousSymmetry, ...]]] = {}
_CACHE_MAX = 256
#: Bump when detection changes, so stale on-disk results are not reused.
_DISK_VERSION = 1


@dataclass(frozen=True)
class _Surface:
    """Surface samples of one mesh (metres) and what the deviation test needs."""

    probes: np.ndarray          # (P, 3) points moved by candidate symmetries
    tree: cKDTree               # over the reference points
    normals: np.ndarray         # (R, 3) unit normals of the reference points
    spacing: float              # allowance for the gaps between reference points: twice the median (metres)
    centroid: np.ndarray        # area-weighted surface centroid (3,)
    bbox_center: np.ndarray     # (3,)
    diameter: float
    vertices: np.ndarray        # mesh vertices (V, 3): corners give exact flip axes of prisms
    probe_colors: np.ndarray | None = None  # (P, 3) in [0, 1]; None: shape only
    ref_colors: np.ndarray | None = None    # (R, 3) in [0, 1]


def _mesh_hash(mesh: trimesh.Trimesh) -> str:
    h = hashlib.sha1()
    h.update(np.round(np.asarray(mesh.vertices), 7).astype(np.float64).tobytes())
    h.update(np.asarray(mesh.faces).astype(np.int64).tobytes())
    return h.hexdigest()


def _diameter(mesh: trimesh.Trimesh) -> float:
    """Largest vertex distance (metres), from the convex hull."""
    hull = np.asarray(mesh.convex_hull.vertices)
    return float(max(np.linalg.norm(hull[i:i + 512, None] - hull[None], axis=-1).max()
                     for i in range(0, len(hull), 512)))


def _surface(mesh: trimesh.Trimesh, mesh_hash: str, diameter: float, appearance: Appearance | None = None
             ) -> _Surface:
    rng = np.random.default_rng([int(mesh_hash[:12], 16), 11])
    ref, fidx = trimesh.sample.sample_surface(mesh, _NUM_REFERENCE, seed=rng)
    probes, pidx = trimesh.sample.sample_surface(mesh, _NUM_PROBES, seed=rng)
    normals = np.asarray(mesh.face_normals)[fidx]
    tree = cKDTree(ref)
    gap, _ = tree.query(probes)  # the identity's distances: pure sampling gaps
    tri = np.asarray(mesh.triangles)
    area = np.asarray(mesh.area_faces)
    centroid = (area[:, None] * tri.mean(axis=1)).sum(axis=0) / area.sum()
    colors: tuple[np.ndarray | None, np.ndarray | None] = (None, None)
    if appearance is not None and appearance.kind != "none":
        colors = tuple(surface_colors(appearance, mesh.faces, f, points_to_barycentric(tri[f], pts))
                       for pts, f in ((probes, pidx), (ref, fidx)))
        if np.ptp(colors[1], axis=0).max() < 2.0 / 255.0:  # one colour all over: the shape decides alone
            colors = (None, None)
    return _Surface(np.asarray(probes), tree, normals, 2.0 * float(np.median(gap)), centroid,
                    0.5 * (mesh.bounds[0] + mesh.bounds[1]), diameter, np.asarray(mesh.vertices), *colors)


def _deviation(s: _Surface, T: np.ndarray, limit: float) -> float:
    """Largest distance (metres) from the moved probes to the surface, as described in the module docstring.

    Distances beyond ``limit`` are not resolved: the result is then ``inf``. The first probes are tried
    alone first, so most wrong candidates cost little.
    """
    moved = s.probes @ T[:3, :3].T + T[:3, 3]
    worst = 0.0
    nearest = []
    for chunk in (moved[:100], moved[100:]):
        dist, idx = s.tree.query(chunk, k=_NEIGHBOURS, distance_upper_bound=limit + s.spacing)
        if not np.all(np.isfinite(dist[:, 0])):
            return float("inf")
        idx = np.minimum(idx, len(s.normals) - 1)  # missing neighbours (inf distance) point past the end
        plane = np.abs(np.einsum("ikj,ikj->ik", chunk[:, None, :] - s.tree.data[idx], s.normals[idx]))
        worst = max(worst, float(np.maximum(plane, dist - s.spacing).min(axis=1).max()))
        if worst > limit:
            return worst
        nearest.append(idx[:, 0])
    if s.probe_colors is not None and _color_mismatch(s, np.concatenate(nearest)) > COLOR_MISMATCH:
        return float("inf")  # the shape maps onto itself, the colours do not
    return worst


def _color_mismatch(s: _Surface, nearest: np.ndarray) -> float:
    """Share of the probes whose colour differs (by more than :data:`COLOR_TOLERANCE` in a channel) from that
    of the reference point nearest to where a candidate moved them."""
    diff = np.abs(s.probe_colors - s.ref_colors[nearest]).max(axis=1)
    return float(np.mean(diff > COLOR_TOLERANCE))


def _rotation(axis: np.ndarray, angle: float, point: np.ndarray) -> np.ndarray:
    """4x4 rotation by ``angle`` about the line through ``point`` along ``axis`` (metres)."""
    R = np.round(rotation_about(axis, angle), 12) + 0.0
    T = np.eye(4)
    T[:3, :3] = R
    T[:3, 3] = point - R @ point
    return T


def _principal_axes(mesh: trimesh.Trimesh, centroid: np.ndarray) -> np.ndarray:
    """Eigenvectors (rows) of the surface's second moment about ``centroid`` (exact over the triangles)."""
    tri = np.asarray(mesh.triangles) - centroid
    area = np.asarray(mesh.area_faces)
    s = tri.sum(axis=1)
    cov = (np.einsum("f,fvi,fvj->ij", area, tri, tri) + np.einsum("f,fi,fj->ij", area, s, s)) / 12.0
    return np.linalg.eigh(cov)[1].T


def _add_axis(axes: list[np.ndarray], axis: np.ndarray) -> None:
    axis = np.asarray(axis, dtype=np.float64)
    n = np.linalg.norm(axis)
    if n < 1e-12:
        return
    axis = axis / n
    if axis[np.argmax(np.abs(axis))] < 0:
        axis = -axis
    if all(abs(float(a @ axis)) < 1.0 - 1e-9 for a in axes):
        axes.append(axis)


def _axis_point(s: _Surface, axis: np.ndarray) -> np.ndarray:
    """The point of the axis line through the centroid nearest the bbox centre (a clean BOP offset)."""
    p = s.centroid + axis * float((s.bbox_center - s.centroid) @ axis)
    return np.where(np.abs(p) < 1e-9, 0.0, p)


def _perpendiculars(s: _Surface, axis: np.ndarray, n: int) -> list[np.ndarray]:
    """Directions perpendicular to ``axis`` towards the farthest vertex, and that turned by pi / (2 n)."""
    d = s.vertices - s.centroid
    d = d - np.outer(d @ axis, axis)
    u0 = d[int(np.argmax(np.einsum("ij,ij->i", d, d)))]
    return [u0, rotation_about(axis, np.pi / (2 * n)) @ u0] if n > 0 else [u0]


def _is_continuous(s: _Surface, axis: np.ndarray, limit: float) -> bool:
    point = _axis_point(s, axis)
    return all(_deviation(s, _rotation(axis, a, point), limit) <= limit for a in _CONTINUOUS_ANGLES)


def _folds(s: _Surface, axis: np.ndarray, limit: float) -> list[int]:
    """The n in :data:`_FOLDS` whose rotation by 2 pi / n about ``axis`` is a symmetry."""
    point = _axis_point(s, axis)
    return [n for n in _FOLDS if _deviation(s, _rotation(axis, 2 * np.pi / n, point), limit) <= limit]


def _same(a: np.ndarray, b: np.ndarray, diameter: float) -> bool:
    return bool(np.allclose(a[:3, :3], b[:3, :3], atol=1e-6) and np.allclose(a[:3, 3], b[:3, 3],
                                                                                atol=1e-6 * diameter))


def _group(generators: "Sequence[np.ndarray]", diameter: float) -> list[np.ndarray]:
    """The group generated by the given transforms (identity first), at most :data:`_MAX_GROUP` elements."""
    elements = [np.eye(4)]
    frontier = [np.eye(4)]
    while frontier and len(elements) < _MAX_GROUP:
        new = []
        for e in frontier:
            for g in generators:
                m = g @ e
                m[:3, :3] = np.round(m[:3, :3], 12) + 0.0
                if not any(_same(m, x, diameter) for x in elements):
                    elements.append(m)
                    new.append(m)
        frontier = new
    return elements[:_MAX_GROUP]


def _flip_axes(s: _Surface, axis: np.ndarray, candidates: list[np.ndarray]) -> list[np.ndarray]:
    """Candidate axes perpendicular to ``axis``: the listed ones, then the direction to the farthest point."""
    out = [c for c in candidates if abs(float(c @ axis)) < 1e-9]
    for u in _perpendiculars(s, axis, 0):
        _add_axis(out, u)
    return out


def detect_symmetries(obj: ObjectModel | trimesh.Trimesh, tol: float = DEFAULT_TOLERANCE, colors: bool = True
                      ) -> tuple[list[np.ndarray], list[ContinuousSymmetry]]:
    """Rotational symmetries of a mesh, found by surface distance (see the module docstring).

    Args:
        obj: An :class:`ObjectModel` or a triangle mesh (metres; any units work, offsets come out in them).
        tol: Largest surface deviation of a symmetry as a fraction of the diameter (0.01: 1 %).
        colors: Whether an object's colours (``obj.appearance``) must map too; a bare mesh has none.

    Returns:
        ``(discrete, continuous)`` in BOP form: 4x4 transforms (identity excluded; with a continuous
        symmetry, only the half turn that reverses its axis, if there is one), and at most one continuous
        symmetry (axis and a point on it, metres).
    """
    if not 0 < tol < 0.5:
        raise ConfigError(f"symmetry tolerance must be in (0, 0.5) (fraction of the diameter), got {tol!r}")
    appearance = None
    if isinstance(obj, ObjectModel):
        mesh, mesh_hash, diameter = obj.mesh, obj.mesh_hash, float(obj.diameter)
        appearance = obj.appearance if colors and uses_colors(obj) else None
    else:
        mesh, mesh_hash = obj, _mesh_hash(obj)
        diameter = _diameter(mesh)
    key_hash = mesh_hash if appearance is None else f"{mesh_hash}_c{_appearance_hash(appearance)}"
    key = (key_hash, float(tol))
    if key not in _CACHE:
        if len(_CACHE) >= _CACHE_MAX:
            _CACHE.pop(next(iter(_CACHE)))
        found = _read_cached(key_hash, tol)
        if found is None:
            if isinstance(obj, ObjectModel):
                _say_why_detected(obj, key_hash, tol)
            found = _detect(mesh, mesh_hash, diameter, tol, appearance)
            _write_cached(key_hash, tol, found)
        _CACHE[key] = found
    discrete, continuous = _CACHE[key]
    return [d.copy() for d in discrete], list(continuous)


def _say_why_detected(obj: ObjectModel, key_hash: str, tol: float) -> None:
    """Log one line when symmetries this source had in the cache are detected again for a changed key."""
    from simtest.objects.cache import key_change

    key = {"units": obj.extra.get("units"), "scale": obj.extra.get("scale"), "tolerance": float(tol),
           "version": _DISK_VERSION, "colours": "_c" in key_hash, "mesh": key_hash}
    why = key_change("symmetry", obj.source, key)
    if why:
        log.warning("%s: symmetries detected again: the cache key changed (%s)", obj.source or obj.name, why)


def uses_colors(obj: ObjectModel) -> bool:
    """Whether detection under ``symmetry="auto"`` compares ``obj``'s colours (it has a texture or colours
    per vertex or face)."""
    return obj.appearance is not None and obj.appearance.kind != "none"


def _appearance_hash(appearance: Appearance) -> str:
    """A short hash of an appearance's arrays (the cache key of colour-aware results)."""
    h = hashlib.sha1(appearance.kind.encode())
    for arr in (appearance.texture, appearance.face_uv, appearance.vertex_colors, appearance.face_colors):
        if arr is not None:
            h.update(str(arr.shape).encode())
            h.update(np.ascontiguousarray(arr).tobytes())
    return h.hexdigest()[:16]


def symmetry_cache_path(mesh_hash: str, tol: float = DEFAULT_TOLERANCE) -> Path:
    """The on-disk cache file of the symmetries detected for a mesh hash and tolerance."""
    from simtest.objects.cache import cache_dir

    return cache_dir() / "symmetry" / f"{mesh_hash}_v{_DISK_VERSION}_{float(tol):g}.json"


def _read_cached(mesh_hash: str, tol: float
                 ) -> tuple[tuple[np.ndarray, ...], tuple[ContinuousSymmetry, ...]] | None:
    """Cached symmetries (metres) or ``None``; an unreadable entry is ignored (and recomputed)."""
    path = symmetry_cache_path(mesh_hash, tol)
    if not path.is_file():
        return None
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
        discrete = tuple(np.asarray(T, dtype=np.float64).reshape(4, 4) for T in data["discrete"])
        continuous = tuple(ContinuousSymmetry(tuple(float(v) for v in c["axis"]), tuple(float(v) for v in c["offset"]))
                           for c in data["continuous"])
    except (OSError, ValueError, KeyError, TypeError) as exc:
        log.warning("ignoring unreadable symmetry cache %s: %s", path, exc)
        return None
    return discrete, continuous


def _write_cached(mesh_hash: str, tol: float,
                  found: tuple[tuple[np.ndarray, ...], tuple[ContinuousSymmetry, ...]]) -> None:
    discrete, continuous = found
    atomic_write_json(symmetry_cache_path(mesh_hash, tol), {
        "discrete": [np.asarray(T, dtype=np.float64).reshape(-1).tolist() for T in discrete],
        "continuous": [{"axis": list(c.axis), "offset": list(c.offset)} for c in continuous]})


def _detect(mesh: trimesh.Trimesh, mesh_hash: str, diameter: float, tol: float, appearance: Appearance | None = None
            ) -> tuple[tuple[np.ndarray, ...], tuple[ContinuousSymmetry, ...]]:
    s = _surface(mesh, mesh_hash, diameter, appearance)
    limit = tol * diameter
    axes: list[np.ndarray] = []
    for a in np.eye(3):
        _add_axis(axes, a)
    for a in _principal_axes(mesh, s.centroid):
        _add_axis(axes, a)
    for axis in axes:
        if _is_continuous(s, axis, limit):
            point = _axis_point(s, axis)
            flips = [_rotation(u, np.pi, point) for u in _flip_axes(s, axis, axes)]
            flip = next((T for T in flips if _deviation(s, T, limit) <= limit), None)
            cont = ContinuousSymmetry(tuple(float(x) for x in axis), tuple(float(x) for x in point))
            return (() if flip is None else (flip,)), (cont,)
    generators = []
    i = 0
    while i < len(axes):  # axes found along the way are appended and tried too
        axis = axes[i]
        folds = _folds(s, axis, limit)
        generators += [_rotation(axis, 2 * np.pi / n, _axis_point(s, axis)) for n in folds]
        if folds and max(folds) >= 3:
            for u in _perpendiculars(s, axis, max(folds)):
                _add_axis(axes, u)
        i += 1
    group = _group(generators, diameter)[1:] if generators else []
    return tuple(T for T in group if _deviation(s, T, limit) <= limit), ()


def apply_symmetry_policy(objects: ObjectSet, policy: str = "auto", tol: float = DEFAULT_TOLERANCE,
                          progress: bool | None = None) -> ObjectSet:
    """The set with detected symmetries on the objects that declare none (``policy="auto"``).

    An object keeps its own symmetries when it declares any, or when ``extra["symmetry"]`` is already set
    (``"declared"`` by a manifest, even one that declares no symmetry). Each object without them records
    ``extra["symmetry"]``: ``"detected"`` (used; ``extra["symmetry_by"]`` says ``"shape"`` or ``"shape and
    colours"``), or ``"off"`` (``policy="none"``: not detected). ``policy="geometry"`` detects by shape alone. A
    :class:`~simtest.objects.lazy.LazyObjectSet` gets the policy applied to each object as it is read.

    A set read now is examined object by object under a progress bar with ETA
    (:class:`~simtest.objects.progress.ObjectProgress`): it appears when the work takes more than a few seconds
    (detection not cached yet), names the object being examined, and work over 10 s ends with a line naming the
    slowest object. ``progress``: draw it (``None``: unless the ``simtest`` logger is set to errors only).

    Raises:
        ConfigError: ``policy`` is not one of :data:`SYMMETRY_POLICIES`.
    """
    if policy not in SYMMETRY_POLICIES:
        raise ConfigError(f"symmetry must be one of {', '.join(SYMMETRY_POLICIES)}, got {policy!r}")
    if type(objects) is not ObjectSet:  # a lazy set applies the policy as each object is read
        return objects.mapped(lambda obj: with_symmetry_policy(obj, policy, tol))
    from simtest.objects.progress import ObjectProgress

    out = []
    with ObjectProgress(len(objects), "symmetries", progress) as bar:
        for obj in objects:
            with bar.step(obj.name):
                out.append(with_symmetry_policy(obj, policy, tol))
    return ObjectSet(out, objects.name)


def with_symmetry_policy(obj: ObjectModel, policy: str = "auto", tol: float = DEFAULT_TOLERANCE) -> ObjectModel:
    """One object under :func:`apply_symmetry_policy` (``policy`` already checked)."""
    if obj.is_symmetric or "symmetry" in obj.extra:
        return obj
    if policy == "none":
        return dataclasses.replace(obj, extra={**obj.extra, "symmetry": "off"})
    colors = policy == "auto" and uses_colors(obj)
    discrete, continuous = detect_symmetries(obj, tol, colors=colors)
    return dataclasses.replace(obj, symmetries_discrete=tuple(discrete), symmetries_continuous=tuple(continuous),
                               extra={**obj.extra, "symmetry": "detected",
                                      "symmetry_by": "shape and colours" if colors else "shape"})


def symmetry_status(obj: ObjectModel, tol: float = DEFAULT_TOLERANCE) -> str:
    """Text for tables: the symmetry label and where it comes from.

    ``continuous(z)`` (declared or built in), ``continuous(z) detected`` (detected and used; by shape, the
    object has no colours), ``none detected (shape and colours)`` / ``discrete(23) detected (shape only)``
    (an object with colours, detected with / without them), or ``continuous(z) detected, not used`` (detection
    turned off; detected here for display).
    """
    state = obj.extra.get("symmetry")
    if state == "detected":
        by = obj.extra.get("symmetry_by", "shape")
        how = "" if not uses_colors(obj) else " (shape and colours)" if by != "shape" else " (shape only)"
        return f"{obj.symmetry_label()} detected{how}"
    if state == "off":
        discrete, continuous = detect_symmetries(obj, tol)
        if not discrete and not continuous:
            return "none (detection off)"
        probe = dataclasses.replace(obj, symmetries_discrete=tuple(discrete), symmetries_continuous=tuple(continuous))
        return f"{probe.symmetry_label()} detected, not used"
    return obj.symmetry_label()
