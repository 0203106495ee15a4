"""Antipodal grasp candidates for a parallel-jaw gripper (Franka Panda hand by default).

Gripper frame (all grasp poses are ``T_obj_grasp``: gripper frame -> object model frame, metres):

- **origin**: the centre between the two fingertip contact regions, i.e. the midpoint of the two contact
  points when the fingers close on the object; it lies mid-way along the finger pads.
- **z**: the approach direction, from the palm towards the object (the hand moves along +z to reach the
  grasp, and retreats along -z).
- **y**: the closing axis; the fingers move along +-y (as the Panda's finger joints in the hand frame).
- **x**: ``y x z`` (right-handed), across the finger width.

With :data:`PANDA` the fingertips reach ``tip_offset`` = 0.022 m beyond the origin along +z (the contacts
sit at the distal pad centres, as the TCP of :mod:`simtest.robot`); the fingers are ``finger_length`` =
0.054 m long, so the palm face is at ``z = -0.032`` m and the palm extends further along -z. An object can
therefore reach 0.032 m past the contacts towards the palm. Most candidates have their contacts at the
origin; for rims and edges the contacts may instead sit up to ``max(contact_shifts)`` = 0.012 m further
along +z (nearer the fingertips, still on the pads); ``contacts`` holds the exact points. ``widths`` are
the distances between the two contacts; the fingers should open to ``min(width + gripper.clearance,
gripper.max_width)`` before closing. A rotation by pi about z gives the
same grasp with the fingers swapped.

Candidates are sampled deterministically (seeded from the mesh hash): surface points with their outward
normals; rays cast inwards along ``-normal``; every point where such a ray leaves the solid is an opposite
contact (so a cup is grasped across a wall or around its whole body); a pair is kept when the opposite
normal lies within the friction cone (``mu``) of the closing axis and the width fits the opening; several
approach directions are tried around each closing axis; candidates whose fingers (swept from the open to
the closed width) or palm would cut the surface are rejected; the rest are scored by antipodality and
closeness to the centre of mass, and de-duplicated. Finally candidates whose open gripper (the fingers at
the opening they have before closing, and the palm) would sit inside the object's collision geometry (the
convex parts MuJoCo collides, which can be larger than the mesh: a hull, or the parts of a decomposition)
are dropped, so every candidate can be reached in simulation. The set is cached in-process per mesh hash.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import trimesh
from scipy.spatial import cKDTree

if TYPE_CHECKING:
    from simtest.objects.model import ObjectModel

__all__ = ["Gripper", "PANDA", "GraspSet", "sample_grasps", "gripper_boxes", "penetrating"]


@dataclass(frozen=True)
class Gripper:
    """A parallel-jaw gripper as simple boxes, metres (see the module docstring for the frame).

    Attributes:
        max_width: Largest opening between the fingers.
        finger_length: Finger length along z from the palm face to the tip (the grasp depth).
        tip_offset: How far the fingertips reach beyond the origin (the contacts) along +z.
        finger_width: Finger extent along x.
        finger_thickness: Finger extent along the closing axis y.
        palm_size: Palm box extents (x, y, z); its +z face is where the fingers start.
        clearance: Extra opening beyond the contact width before closing (sum over both fingers).
        min_width: Narrowest contact width accepted.
        contact_shifts: Where along z the contacts may sit on the pads (0: at the origin; 0.012: 12 mm
            towards the fingertips, for rims and edges). Grasps with a shift score slightly lower.
    """

    max_width: float = 0.08
    finger_length: float = 0.054
    tip_offset: float = 0.022
    finger_width: float = 0.02
    finger_thickness: float = 0.01
    palm_size: tuple[float, float, float] = (0.06, 0.21, 0.06)
    clearance: float = 0.01
    min_width: float = 0.002
    contact_shifts: tuple[float, ...] = (0.0, 0.012)

    @property
    def max_contact_width(self) -> float:
        """Widest contact distance that still leaves ``clearance`` when fully open (metres)."""
        return self.max_width - self.clearance

    def open_width(self, width: float | np.ndarray) -> float | np.ndarray:
        """Opening before closing on a contact width (metres)."""
        return np.minimum(np.asarray(width) + self.clearance, self.max_width)


#: The Franka Emika Panda hand.
PANDA = Gripper()


def gripper_boxes(width: float, gripper: Gripper = PANDA, inner_tolerance: float = 0.0) -> np.ndarray:
    """Boxes ``[[lo_x, lo_y, lo_z], [hi_x, hi_y, hi_z]]`` (3, 2, 3) in the gripper frame, metres.

    The two fingers closed on a contact ``width`` (their inner faces moved outwards by ``inner_tolerance``),
    and the palm.
    """
    g = gripper
    tip = g.tip_offset
    base = tip - g.finger_length
    fx = g.finger_width / 2
    lo = width / 2 + inner_tolerance
    hi = width / 2 + g.finger_thickness
    px, py, pz = (s / 2 for s in g.palm_size)
    return np.array([
        [[-fx, lo, base], [fx, hi, tip]],
        [[-fx, -hi, base], [fx, -lo, tip]],
        [[-px, -py, base - g.palm_size[2]], [px, py, base]],
    ])


@dataclass(frozen=True)
class GraspSet:
    """Grasp candidates in one frame (the object model frame unless transformed).

    Attributes:
        poses: (N, 4, 4) gripper frames (see the module docstring), translations in metres.
        widths: (N,) contact widths, metres.
        scores: (N,) quality in [0, 1], higher is better.
        contacts: (N, 2, 3) the two contact points, metres (same frame as ``poses``).
    """

    poses: np.ndarray
    widths: np.ndarray
    scores: np.ndarray
    contacts: np.ndarray = field(default=None)  # type: ignore[assignment]

    def __post_init__(self) -> None:
        poses = np.asarray(self.poses, dtype=np.float64).reshape(-1, 4, 4)
        n = len(poses)
        widths = np.asarray(self.widths, dtype=np.float64).reshape(-1)
        scores = np.asarray(self.scores, dtype=np.float64).reshape(-1)
        contacts = (np.full((n, 2, 3), np.nan) if self.contacts is None
                    else np.asarray(self.contacts, dtype=np.float64).reshape(-1, 2, 3))
        if not (len(widths) == len(scores) == len(contacts) == n):
            raise ValueError(f"GraspSet: poses, widths, scores and contacts must have the same length, got "
                             f"{n}, {len(widths)}, {len(scores)}, {len(contacts)}")
        if n and (scores.min() < 0 or scores.max() > 1):
            raise ValueError(f"GraspSet: scores must lie in [0, 1], got [{scores.min()}, {scores.max()}]")
        for name, arr in (("poses", poses), ("widths", widths), ("scores", scores), ("contacts", contacts)):
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @staticmethod
    def empty() -> "GraspSet":
        return GraspSet(np.zeros((0, 4, 4)), np.zeros(0), np.zeros(0), np.zeros((0, 2, 3)))

    def __len__(self) -> int:
        return len(self.poses)

    def __getitem__(self, index) -> "GraspSet":
        """A subset (``index``: int, slice, index array or boolean mask)."""
        if isinstance(index, (int, np.integer)):
            index = [int(index)]
        return GraspSet(self.poses[index], self.widths[index], self.scores[index], self.contacts[index])

    def best(self, k: int = 1) -> "GraspSet":
        """The ``k`` highest-scoring candidates, best first (ties keep their order)."""
        order = np.argsort(-self.scores, kind="stable")[:max(int(k), 0)]
        return self[order]

    def transformed(self, T: np.ndarray) -> "GraspSet":
        """The candidates expressed in another frame: ``T_new_obj @ pose`` (T is 4x4, metres)."""
        T = np.asarray(T, dtype=np.float64).reshape(4, 4)
        contacts = self.contacts @ T[:3, :3].T + T[:3, 3]
        return GraspSet(T @ self.poses, self.widths, self.scores, contacts)

    def __repr__(self) -> str:
        return f"GraspSet({len(self)} grasps)"


_CACHE: dict[tuple, GraspSet] = {}
_CACHE_MAX = 256


def sample_grasps(obj: "ObjectModel", gripper: Gripper = PANDA, *, mu: float = 0.5, num_points: int = 512,
                  num_approaches: int = 12, max_grasps: int = 200, max_pairs: int = 400) -> GraspSet:
    """Antipodal parallel-jaw grasp candidates for ``obj`` in its model frame (cached per mesh hash).

    Args:
        obj: The object (any object with ``mesh``, ``mesh_hash``, ``center_of_mass`` and ``diameter``).
        gripper: Gripper geometry (metres).
        mu: Friction coefficient; the opposite contact normal must lie within ``atan(mu)`` of the axis.
        num_points: Surface points sampled as first contacts.
        num_approaches: Approach directions tried around each closing axis.
        max_grasps: Most candidates returned.
        max_pairs: Most distinct contact pairs checked for collisions (bounds the run time).

    Returns:
        The candidates sorted by score, best first; empty when nothing fits the gripper.
    """
    concave = bool(getattr(obj, "is_concave", False))
    key = (obj.mesh_hash, gripper, float(mu), int(num_points), int(num_approaches), int(max_grasps), int(max_pairs),
           concave)
    hit = _CACHE.get(key)
    if hit is not None:
        return hit
    result = _sample(obj.mesh, obj.mesh_hash, np.asarray(obj.center_of_mass), float(obj.diameter), gripper,
                     mu, num_points, num_approaches, max_grasps, max_pairs)
    parts = getattr(obj, "collision_parts", None)
    if parts is not None and len(result):
        result = result[~penetrating(result, parts, gripper)]
    if len(_CACHE) >= _CACHE_MAX:
        _CACHE.pop(next(iter(_CACHE)))
    _CACHE[key] = result
    return result


def _sample(mesh: trimesh.Trimesh, mesh_hash: str, com: np.ndarray, diameter: float, g: Gripper, mu: float,
            num_points: int, num_approaches: int, max_grasps: int, max_pairs: int) -> GraspSet:
    rng = np.random.default_rng([int(mesh_hash[:12], 16), 7])
    pts, fidx = trimesh.sample.sample_surface(mesh, num_points, seed=rng)
    normals = np.asarray(mesh.face_normals)[fidx]
    # --- opposite contacts: where the inward ray leaves the solid ---------------------------------------
    eps = 1e-6
    origins = pts - normals * eps
    dirs = -normals
    locs, ray_idx, tri_idx = mesh.ray.intersects_location(origins, dirs, multiple_hits=True)
    if len(locs) == 0:
        return GraspSet.empty()
    exit_ok = np.einsum("ij,ij->i", np.asarray(mesh.face_normals)[tri_idx], dirs[ray_idx]) > 0
    widths = np.linalg.norm(locs - pts[ray_idx], axis=1)
    cos_mu = 1.0 / np.sqrt(1.0 + mu * mu)
    cos_q = np.einsum("ij,ij->i", np.asarray(mesh.face_normals)[tri_idx], dirs[ray_idx])
    keep = exit_ok & (widths >= g.min_width) & (widths <= g.max_contact_width) & (cos_q >= cos_mu)
    if not np.any(keep):
        return GraspSet.empty()
    p = pts[ray_idx[keep]]
    q = locs[keep]
    w = widths[keep]
    axis = dirs[ray_idx[keep]]
    centers = 0.5 * (p + q)
    s_anti = np.clip((cos_q[keep] - cos_mu) / (1.0 - cos_mu), 0.0, 1.0)
    s_com = np.clip(1.0 - np.linalg.norm(centers - com, axis=1) / (0.5 * diameter), 0.0, 1.0)
    pair_score = 0.5 * s_anti + 0.5 * s_com
    # --- de-duplicate contact pairs before the (costlier) collision checks ------------------------------
    order = np.argsort(-pair_score, kind="stable")
    chosen: list[int] = []
    for i in order:
        if chosen:
            c = np.asarray(chosen)
            close = np.linalg.norm(centers[c] - centers[i], axis=1) < 0.006
            parallel = np.abs(axis[c] @ axis[i]) > np.cos(np.deg2rad(20.0))
            if np.any(close & parallel):
                continue
        chosen.append(int(i))
        if len(chosen) >= max_pairs:
            break
    sel = np.asarray(chosen)
    p, q, w, axis, centers, s_anti, s_com = p[sel], q[sel], w[sel], axis[sel], centers[sel], s_anti[sel], s_com[sel]
    # --- approach directions and collision checks ---------------------------------------------------------
    cloud = np.concatenate([np.asarray(mesh.vertices),
                            trimesh.sample.sample_surface(mesh, 8000, seed=rng)[0]])
    tree = cKDTree(cloud)
    boxes_r = float(np.linalg.norm(np.max(np.abs(gripper_boxes(g.max_width, g)), axis=(0, 1))))
    theta = 2.0 * np.pi * np.arange(num_approaches) / num_approaches
    ct, st = np.cos(theta)[:, None], np.sin(theta)[:, None]
    poses, out_w, out_s, out_c = [], [], [], []
    for i in range(len(sel)):
        y = axis[i]
        u = _perpendicular(y)
        v = np.cross(y, u)  # (u, v, y) right-handed: y x u = v
        open_w = float(g.open_width(w[i]))
        lo_hi = gripper_boxes(w[i], g, inner_tolerance=0.002)
        # the fingers sweep from the open width to the contact: extend their outer faces
        lo_hi[0, 1, 1] = open_w / 2 + g.finger_thickness
        lo_hi[1, 0, 1] = -(open_w / 2 + g.finger_thickness)
        nb = tree.query_ball_point(centers[i], boxes_r)
        d = cloud[nb] - centers[i]
        py, pu, pv = d @ y, d @ u, d @ v
        pz = ct * pu + st * pv          # (A, P)
        px = ct * pv - st * pu
        for shift, factor in zip(g.contact_shifts, (1.0, 0.95, 0.9)):
            hit = np.zeros(num_approaches, dtype=bool)
            for lo, hi in lo_hi:
                inside = ((px >= lo[0]) & (px <= hi[0]) & (py >= lo[1]) & (py <= hi[1])
                          & (pz + shift >= lo[2]) & (pz + shift <= hi[2]))
                hit |= inside.any(axis=1)
            for k in np.flatnonzero(~hit):
                z = ct[k, 0] * u + st[k, 0] * v
                x = np.cross(y, z)
                T = np.eye(4)
                T[:3, 0], T[:3, 1], T[:3, 2], T[:3, 3] = x, y, z, centers[i] - shift * z
                poses.append(T)
                out_w.append(w[i])
                out_s.append(factor * (0.5 * s_anti[i] + 0.5 * s_com[i]))
                out_c.append((p[i], q[i]))
    if not poses:
        return GraspSet.empty()
    poses_a, w_a, s_a, c_a = np.stack(poses), np.asarray(out_w), np.asarray(out_s), np.asarray(out_c)
    keep_idx = _dedupe(poses_a, s_a, max_grasps)
    return GraspSet(poses_a[keep_idx], w_a[keep_idx], s_a[keep_idx], c_a[keep_idx])


def _box_points(box: np.ndarray, counts: tuple[int, int, int]) -> np.ndarray:
    """A grid of points (N, 3) through a box ``[[lo], [hi]]``, its faces included."""
    axes = [np.linspace(box[0, i], box[1, i], counts[i]) for i in range(3)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def penetrating(grasps: GraspSet, parts, gripper: Gripper = PANDA, margin: float = 0.001) -> np.ndarray:
    """Which candidates (bool (N,)) put the open gripper more than ``margin`` metres into a convex part.

    The gripper is the palm and the two fingers opened to ``gripper.open_width(width)`` (its pose before
    closing). A box and a part overlap when a grid point of the box lies inside the part or a vertex of
    the part inside the box, each by more than ``margin``.

    Args:
        grasps: Candidates in the model frame.
        parts: Convex meshes in the model frame (e.g. :attr:`ObjectModel.collision_parts`), metres.
        gripper: Gripper geometry.
        margin: Penetration tolerated (metres): touching is not penetrating.
    """
    n = len(grasps)
    hit = np.zeros(n, dtype=bool)
    if n == 0:
        return hit
    open_w = np.asarray(gripper.open_width(grasps.widths), dtype=np.float64)
    boxes = np.stack([gripper_boxes(float(w), gripper) for w in open_w])  # (N, 3, 2, 3)
    counts = ((3, 3, 7), (3, 3, 7), (5, 11, 4))
    local = np.concatenate([np.stack([_box_points(b[k], counts[k]) for b in boxes]) for k in range(3)], axis=1)
    R, t = grasps.poses[:, :3, :3], grasps.poses[:, :3, 3]
    world = np.einsum("nij,npj->npi", R, local) + t[:, None, :]  # (N, P, 3), model frame
    for part in parts:
        normals = np.asarray(part.face_normals)
        offsets = -np.einsum("ij,ij->i", normals, np.asarray(part.triangles)[:, 0])
        verts = np.asarray(part.vertices)
        lo, hi = part.bounds
        near = np.flatnonzero(~hit & np.all((world.max(axis=1) >= lo) & (world.min(axis=1) <= hi), axis=1))
        for chunk in np.array_split(near, max(1, len(near) // 16)):
            if len(chunk) == 0:
                continue
            w = world[chunk]
            # (C, P, F) plane distances, <= 0 inside every face; elementwise (no BLAS threads: predictable
            # on a busy machine)
            signed = w[..., 0:1] * normals[:, 0] + w[..., 1:2] * normals[:, 1] + w[..., 2:3] * normals[:, 2] + offsets
            hit[chunk] |= (signed.max(axis=2) < -margin).any(axis=1)
            v = np.einsum("cji,cvj->cvi", R[chunk], verts[None] - t[chunk, None, :])  # vertices, gripper frame
            b = boxes[chunk]  # (C, 3, 2, 3)
            inside = (v[:, :, None, :] > b[:, None, :, 0] + margin) & (v[:, :, None, :] < b[:, None, :, 1] - margin)
            hit[chunk] |= inside.all(axis=3).any(axis=(1, 2))
    return hit


def _perpendicular(a: np.ndarray) -> np.ndarray:
    """A unit vector perpendicular to unit ``a``, chosen deterministically."""
    helper = np.array([0.0, 0.0, 1.0]) if abs(a[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = np.cross(a, helper)
    return u / np.linalg.norm(u)


def _dedupe(poses: np.ndarray, scores: np.ndarray, max_grasps: int, dist: float = 0.005,
            angle_deg: float = 20.0) -> np.ndarray:
    """Greedy non-maximum suppression: indices of kept grasps, best first.

    Two grasps are duplicates when their origins are within ``dist`` metres and their rotations differ by
    less than ``angle_deg`` (a grasp and its finger-swapped twin, rotated by pi about z, count as equal).
    """
    order = np.argsort(-scores, kind="stable")
    cos_lim = np.cos(np.deg2rad(angle_deg))
    kept: list[int] = []
    for i in order:
        if kept:
            k = np.asarray(kept)
            near = np.linalg.norm(poses[k, :3, 3] - poses[i, :3, 3], axis=1) < dist
            if np.any(near):
                same_z = np.einsum("nj,j->n", poses[k][near][:, :3, 2], poses[i, :3, 2]) > cos_lim
                same_y = np.abs(np.einsum("nj,j->n", poses[k][near][:, :3, 1], poses[i, :3, 1])) > cos_lim
                if np.any(same_z & same_y):
                    continue
        kept.append(int(i))
        if len(kept) >= max_grasps:
            break
    return np.asarray(kept, dtype=np.int64)
