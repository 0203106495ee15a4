"""``ObjectModel``: one rigid object with exact geometry and metadata; ``ObjectSet``: a set of them.

Geometry is in metres, in the BOP model frame: origin at the centre of the axis-aligned 3D bounding box,
Z up. Derived data that costs time (surface samples, keypoints, collision hulls, grasp candidates) is computed
on first use and cached on the instance; collision hulls are also cached on disk keyed by the mesh hash.
"""

from __future__ import annotations

import functools
import hashlib
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass, field

import numpy as np
import trimesh

from simtest.errors import AssetError
from simtest.objects.cache import cache_dir
from simtest.objects.appearance import Appearance
from simtest.objects.collision import convex_parts, open_mesh_is_concave
from simtest.objects.grasps import sample_grasps
from simtest.objects.symmetry import symmetry_transforms

__all__ = [
    "ContinuousSymmetry",
    "ObjectEntry",
    "ObjectModel",
    "ObjectSet",
    "farthest_point_sampling",
    "cache_dir",
    "mesh_diameter",
]

#: Mesh vertices are rounded to this many decimals (metres) before hashing, so equal geometry hashes equal.
_HASH_DECIMALS = 7


@dataclass(frozen=True)
class ContinuousSymmetry:
    """A continuous rotational symmetry in BOP form: rotation about ``axis`` through ``offset`` (metres)."""

    axis: tuple[float, float, float]
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0)


@dataclass(frozen=True)
class ObjectEntry:
    """What a set knows of an object without reading its mesh: id, name, category and where it comes from."""

    obj_id: int
    name: str
    category: str
    source: str = ""


def farthest_point_sampling(points: np.ndarray, k: int, start: int = 0) -> np.ndarray:
    """Indices of ``k`` points chosen greedily, each the farthest from those chosen before.

    Deterministic: starts at ``points[start]``. ``points`` is (N, 3); returns (k,) int indices.
    """
    n = len(points)
    if k <= 0:
        return np.zeros(0, dtype=np.int64)
    if k > n:
        raise ValueError(f"cannot sample {k} points from {n}")
    chosen = np.empty(k, dtype=np.int64)
    chosen[0] = start
    dist = np.linalg.norm(points - points[start], axis=1)
    for i in range(1, k):
        chosen[i] = int(np.argmax(dist))
        dist = np.minimum(dist, np.linalg.norm(points - points[chosen[i]], axis=1))
    return chosen


@dataclass(frozen=True, eq=False)
class ObjectModel:
    """One rigid object.

    Attributes:
        obj_id: Positive integer id (BOP ``obj_id``), unique within its set.
        name: Human-readable name, e.g. ``"mug_1"``.
        category: Category name for category-level use, e.g. ``"mug"``.
        instance: Index of this instance within its category (0-based).
        mesh: Triangle mesh in metres, origin at the bbox centre, Z up. Treated as read-only.
        density: kg/m^3, used for mass and inertia (a closed, watertight mesh is assumed solid).
        rgba: Material colour (4,), each in [0, 1]; it multiplies the texture of a textured object.
        appearance: Texture and UVs, or colours per vertex or face (``None``: the material colour only).
        symmetries_discrete: 4x4 transforms (metres) mapping the mesh onto itself, identity excluded.
        symmetries_continuous: Continuous rotational symmetries.
        source: Where the geometry came from (``"builtin:<category>:<seed>"`` or a file path).
        num_keypoints: How many farthest-point-sampled surface keypoints :attr:`keypoints_fps` holds.
        concave: Whether collision geometry needs a convex decomposition (``None``: decide from the mesh).
        graspable_override: Force :attr:`graspable` (``None``: decide from the grasp candidates).
        friction: Sliding friction coefficient of the collision geoms (``None``: the scene's default).
    """

    obj_id: int
    name: str
    category: str
    instance: int
    mesh: trimesh.Trimesh
    density: float = 500.0
    rgba: tuple[float, float, float, float] = (0.7, 0.7, 0.7, 1.0)
    symmetries_discrete: tuple[np.ndarray, ...] = ()
    symmetries_continuous: tuple[ContinuousSymmetry, ...] = ()
    source: str = ""
    num_keypoints: int = 8
    concave: bool | None = None
    graspable_override: bool | None = None
    extra: dict = field(default_factory=dict)
    appearance: Appearance | None = None
    friction: float | None = None

    def __post_init__(self) -> None:
        where = self.source or self.name
        if not isinstance(self.obj_id, (int, np.integer)) or isinstance(self.obj_id, bool) or self.obj_id < 1:
            raise AssetError(f"{where}: obj_id must be a positive integer, got {self.obj_id!r}")
        object.__setattr__(self, "obj_id", int(self.obj_id))
        if not (self.density > 0):
            raise AssetError(f"{where}: density must be > 0 kg/m^3, got {self.density!r}")
        validate_mesh(self.mesh, where)
        self.mesh.vertices.flags.writeable = False
        self.mesh.faces.flags.writeable = False
        sym = tuple(np.asarray(s, dtype=np.float64).reshape(4, 4) for s in self.symmetries_discrete)
        object.__setattr__(self, "symmetries_discrete", sym)
        object.__setattr__(self, "rgba", tuple(float(c) for c in self.rgba))
        if self.appearance is not None:
            self.appearance.check(len(self.mesh.vertices), len(self.mesh.faces), where)
        if self.friction is not None and not (0.0 < self.friction <= 10.0):
            raise AssetError(f"{where}: friction must be in (0, 10], got {self.friction!r}")

    # --- geometry ----------------------------------------------------------------------------------------
    @functools.cached_property
    def vertices(self) -> np.ndarray:
        """Mesh vertices (N, 3) float64, metres. Read-only (shared); :meth:`vertices_copy` gives a writable
        copy (e.g. for Open3D's ``Vector3dVector``)."""
        return np.asarray(self.mesh.vertices)

    @functools.cached_property
    def faces(self) -> np.ndarray:
        """Triangle indices (M, 3) int64 into :attr:`vertices`. Read-only; :meth:`faces_copy` gives a writable
        copy."""
        return np.asarray(self.mesh.faces)

    def vertices_copy(self) -> np.ndarray:
        """A writable, C-contiguous float64 copy of :attr:`vertices` (N, 3), metres."""
        return np.array(self.vertices, dtype=np.float64, order="C")

    def faces_copy(self) -> np.ndarray:
        """A writable, C-contiguous int32 copy of :attr:`faces` (M, 3) (the type Open3D's ``Vector3iVector``
        takes)."""
        return np.array(self.faces, dtype=np.int32, order="C")

    @functools.cached_property
    def bbox(self) -> np.ndarray:
        """Axis-aligned bounds ``[[min_x, min_y, min_z], [max_x, max_y, max_z]]``, metres."""
        return np.asarray(self.mesh.bounds, dtype=np.float64)

    @property
    def size(self) -> np.ndarray:
        """Bounding-box extents (3,), metres."""
        return self.bbox[1] - self.bbox[0]

    @functools.cached_property
    def diameter(self) -> float:
        """Largest distance between two mesh vertices (metres), exact: computed on the convex hull."""
        return mesh_diameter(self.mesh)

    @functools.cached_property
    def mesh_hash(self) -> str:
        """SHA-1 of the rounded vertices and faces; keys on-disk caches."""
        h = hashlib.sha1()
        h.update(np.round(self.vertices, _HASH_DECIMALS).astype(np.float64).tobytes())
        h.update(self.faces.astype(np.int64).tobytes())
        return h.hexdigest()

    @functools.cached_property
    def is_watertight(self) -> bool:
        """Whether the mesh is closed (every edge shared by exactly two faces); the mesh is read-only."""
        return bool(self.mesh.is_watertight)

    # --- physics -----------------------------------------------------------------------------------------
    @functools.cached_property
    def mass(self) -> float:
        """kg, from :attr:`density` and the enclosed volume (convex-hull volume if the mesh is not closed)."""
        return float(self.density * self._volume)

    @functools.cached_property
    def _volume(self) -> float:
        vol = float(self.mesh.volume) if self.mesh.is_watertight else 0.0
        if not vol > 0:
            vol = float(self.mesh.convex_hull.volume)
        return vol

    @functools.cached_property
    def inertia(self) -> np.ndarray:
        """3x3 inertia tensor about the centre of mass, in the model frame (kg m^2)."""
        src = self.mesh if (self.mesh.is_watertight and self.mesh.volume > 0) else self.mesh.convex_hull
        m = src.copy()
        m.density = self.density
        return np.asarray(m.moment_inertia, dtype=np.float64)

    @functools.cached_property
    def center_of_mass(self) -> np.ndarray:
        """Centre of mass (3,), model frame, metres."""
        src = self.mesh if (self.mesh.is_watertight and self.mesh.volume > 0) else self.mesh.convex_hull
        return np.asarray(src.center_mass, dtype=np.float64)

    @functools.cached_property
    def is_concave(self) -> bool:
        """Whether the collision geometry needs a convex decomposition (hull volume exceeds mesh by > 5%; for
        a mesh that is not watertight, the solid its surface encloses, see :mod:`simtest.objects.collision`)."""
        if self.concave is not None:
            return bool(self.concave)
        if not self.mesh.is_watertight:
            return open_mesh_is_concave(self.mesh)
        if self.mesh.volume <= 0:
            return False
        return bool(self.mesh.convex_hull.volume > 1.05 * self.mesh.volume)

    @functools.cached_property
    def collision_parts(self) -> tuple[trimesh.Trimesh, ...]:
        """Convex pieces for MuJoCo collision (model frame, metres).

        Convex shapes give their hull; concave ones a CoACD decomposition, cached on disk by mesh hash.
        """
        return convex_parts(self)

    # --- annotations ---------------------------------------------------------------------------------------
    @functools.cached_property
    def surface_points(self) -> np.ndarray:
        """A complete surface point cloud (4096, 3), metres, sampled deterministically (area-uniform)."""
        rng = np.random.default_rng(int(self.mesh_hash[:8], 16))
        pts, _ = trimesh.sample.sample_surface(self.mesh, 4096, seed=rng)
        return np.asarray(pts, dtype=np.float64)

    def surface_cloud(self, count: int = 2000, seed: int = 12345) -> tuple[np.ndarray, np.ndarray]:
        """Area-uniform surface samples with the unit normals of their faces (outward for a consistently
        wound mesh), model frame, metres; the cloud the built-in ``icp`` estimator registers against.

        Deterministic for ``(count, seed)`` and cached per pair on the instance. The arrays are read-only;
        ``np.array(points)`` gives a writable copy.

        Args:
            count: Number of samples.
            seed: Seed of the sampling.

        Returns:
            ``(points (count, 3) float64, normals (count, 3) float64)``.
        """
        if int(count) < 1:
            raise AssetError(f"{self.name}: surface_cloud count must be >= 1, got {count!r}")
        cache = self.__dict__.setdefault("_surface_clouds", {})
        key = (int(count), int(seed))
        if key not in cache:
            pts, face_idx = trimesh.sample.sample_surface(self.mesh, key[0], seed=np.random.default_rng(key[1]))
            points = np.asarray(pts, dtype=np.float64)
            normals = np.array(np.asarray(self.mesh.face_normals)[face_idx], dtype=np.float64)
            points.flags.writeable = False
            normals.flags.writeable = False
            cache[key] = (points, normals)
        return cache[key]

    @functools.cached_property
    def keypoints_bbox(self) -> np.ndarray:
        """The 8 corners (8, 3) of the 3D bounding box, metres; bit i of the index picks max along axis i."""
        lo, hi = self.bbox
        return np.array([[hi[0] if i & 1 else lo[0], hi[1] if i & 2 else lo[1], hi[2] if i & 4 else lo[2]]
                         for i in range(8)])

    @functools.cached_property
    def keypoints_fps(self) -> np.ndarray:
        """``num_keypoints`` farthest-point-sampled surface points (K, 3), metres, on the mesh surface."""
        pts = self.surface_points
        start = int(np.argmax(np.linalg.norm(pts, axis=1)))
        return pts[farthest_point_sampling(pts, min(self.num_keypoints, len(pts)), start)]

    @property
    def nocs_scale(self) -> float:
        """NOCS normalisation: the bbox diagonal (metres); ``x_nocs = x / nocs_scale + 0.5``."""
        return float(np.linalg.norm(self.size))

    def to_nocs(self, points: np.ndarray) -> np.ndarray:
        """Model-frame points (N, 3) in metres -> normalized object coordinates in the unit cube."""
        return np.asarray(points) / self.nocs_scale + 0.5

    # --- symmetry & grasps ---------------------------------------------------------------------------------
    @property
    def is_symmetric(self) -> bool:
        return bool(self.symmetries_discrete or self.symmetries_continuous)

    def symmetry_transforms(self, max_step: float = 0.01) -> np.ndarray:
        """All symmetry transforms (S, 4, 4), identity first, continuous ones discretised as the BOP toolkit.

        Args:
            max_step: Maximum angular step (radians) of a discretised continuous symmetry... expressed as in
                the BOP toolkit's ``max_sym_disc_step`` (0.01: ``ceil(pi / 0.01) = 315`` steps per turn).
        """
        return symmetry_transforms(self.symmetries_discrete, self.symmetries_continuous, max_step)

    @functools.cached_property
    def grasps(self):  # -> simtest.objects.grasps.GraspSet
        """Antipodal parallel-jaw grasp candidates in the model frame (see :mod:`simtest.objects.grasps`)."""
        return sample_grasps(self)

    @property
    def graspable(self) -> bool:
        """Whether at least one grasp candidate fits the Panda gripper."""
        if self.graspable_override is not None:
            return bool(self.graspable_override)
        return len(self.grasps) > 0

    def symmetry_label(self) -> str:
        """Short text for tables: ``none``, ``continuous(z)``, ``discrete(3)``, ``continuous(z)+discrete(1)``."""
        parts = []
        for s in self.symmetries_continuous:
            ax = np.asarray(s.axis, dtype=float)
            name = "xyz"[int(np.argmax(np.abs(ax)))] if np.count_nonzero(np.round(ax, 6)) == 1 else "axis"
            parts.append(f"continuous({name})")
        if self.symmetries_discrete:
            parts.append(f"discrete({len(self.symmetries_discrete)})")
        return "+".join(parts) or "none"

    def __repr__(self) -> str:
        return (f"ObjectModel(obj_id={self.obj_id}, name={self.name!r}, category={self.category!r}, "
                f"diameter={self.diameter * 1000:.1f} mm)")


def mesh_diameter(mesh: trimesh.Trimesh) -> float:
    """Largest distance between two vertices of ``mesh`` (its units), exact: computed on the convex hull."""
    try:
        hull = np.asarray(mesh.convex_hull.vertices)
    except Exception:  # flat or tiny meshes: every vertex
        hull = np.asarray(mesh.vertices)
    best = 0.0
    for start in range(0, len(hull), 512):
        d = np.linalg.norm(hull[start:start + 512, None, :] - hull[None, :, :], axis=-1)
        best = max(best, float(d.max()))
    return best


def validate_mesh(mesh: trimesh.Trimesh, where: str) -> None:
    """Raise :class:`AssetError` naming ``where`` if the mesh is empty, degenerate or non-finite."""
    if not isinstance(mesh, trimesh.Trimesh):
        raise AssetError(f"{where}: expected a triangle mesh, got {type(mesh).__name__}")
    v = np.asarray(mesh.vertices)
    if len(v) == 0 or len(mesh.faces) == 0:
        raise AssetError(f"{where}: mesh is empty ({len(v)} vertices, {len(mesh.faces)} faces)")
    if not np.all(np.isfinite(v)):
        bad = int(np.count_nonzero(~np.isfinite(v).all(axis=1)))
        raise AssetError(f"{where}: mesh has {bad} vertices with NaN or infinite coordinates")
    extent = float(np.ptp(v, axis=0).max())
    if float(mesh.area) <= 0 or extent <= 0 or np.linalg.matrix_rank(v - v.mean(axis=0), tol=1e-9 * extent) < 2:
        raise AssetError(f"{where}: mesh is degenerate (zero area, or all vertices on one point or line)")


class ObjectSet(Sequence[ObjectModel]):
    """An ordered set of objects with unique ids. ``get(obj_id)`` raises listing the known ids.

    Args:
        objects: The objects.
        name: Name of the set (``"builtin"``, a folder path, ...).
    """

    def __init__(self, objects: Iterable[ObjectModel], name: str = "custom") -> None:
        self.name = name
        self._objects = list(objects)
        self._by_id: dict[int, ObjectModel] = {}
        for obj in self._objects:
            if obj.obj_id in self._by_id:
                other = self._by_id[obj.obj_id]
                raise AssetError(
                    f"object set {name!r}: duplicate obj_id {obj.obj_id} ({other.name!r} from "
                    f"{other.source or '?'} and {obj.name!r} from {obj.source or '?'})")
            self._by_id[obj.obj_id] = obj

    def __len__(self) -> int:
        return len(self._objects)

    def __getitem__(self, index):  # type: ignore[override]
        return self._objects[index]

    def __iter__(self) -> Iterator[ObjectModel]:
        return iter(self._objects)

    @property
    def ids(self) -> list[int]:
        return [o.obj_id for o in self._objects]

    def get(self, obj_id: int) -> ObjectModel:
        """The object with ``obj_id``; :class:`AssetError` listing the known ids if there is none."""
        try:
            return self._by_id[int(obj_id)]
        except (KeyError, TypeError, ValueError):
            raise self._unknown_id(obj_id) from None

    def _unknown_id(self, obj_id: object) -> AssetError:
        """The error for an id the set does not hold, listing the ones it does."""
        known = ", ".join(f"{e.obj_id} ({e.name})" for e in self.entries)
        return AssetError(f"unknown object id {obj_id!r} in set {self.name!r}; known ids: {known}")

    def by_name(self, name: str) -> ObjectModel:
        """The object named ``name`` (a lazy set reads only that one)."""
        for e in self.entries:
            if e.name == name:
                return self.get(e.obj_id)
        raise AssetError(f"unknown object name {name!r} in set {self.name!r}; known: "
                         f"{', '.join(e.name for e in self.entries)}")

    #: Whether objects are read when first asked for (:class:`~simtest.objects.lazy.LazyObjectSet`) rather
    #: than all up front.
    lazy: bool = False

    def subset(self, obj_ids: Iterable[int], name: str | None = None) -> "ObjectSet":
        return ObjectSet([self.get(i) for i in obj_ids], name or f"{self.name}-subset")

    def mapped(self, transform: Callable[[ObjectModel], ObjectModel]) -> "ObjectSet":
        """The same set with ``transform`` applied to every object (which must keep its id, name and category)."""
        return ObjectSet([transform(o) for o in self._objects], self.name)

    @property
    def categories(self) -> list[str]:
        return sorted({o.category for o in self._objects})

    @property
    def entries(self) -> list[ObjectEntry]:
        """Id, name, category and source of every object, in set order (a lazy set reads no mesh for them)."""
        return [ObjectEntry(o.obj_id, o.name, o.category, o.source) for o in self._objects]

    def __repr__(self) -> str:
        return f"ObjectSet(name={self.name!r}, {len(self)} objects)"
