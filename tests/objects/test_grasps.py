"""Antipodal grasp candidates: fit the Panda opening, do not penetrate the mesh, API behaviour."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from meshcheck import surface_distance
from simtest.objects import PANDA, GraspSet, ObjectModel, sample_grasps
from simtest.objects.grasps import gripper_boxes


def box_grid(lo: np.ndarray, hi: np.ndarray, shrink: float = 0.001, n: int = 4) -> np.ndarray:
    axes = [np.linspace(a + shrink, b - shrink, n) for a, b in zip(lo, hi)]
    return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def test_grasps_fit_and_do_not_penetrate(builtin):
    for obj in builtin:
        g = obj.grasps
        assert obj.graspable and len(g) > 0, obj.name
        assert len(g) <= 200
        assert np.all(g.widths <= PANDA.max_width) and np.all(g.widths > 0)
        assert np.all((g.scores >= 0) & (g.scores <= 1))
        R = g.poses[:, :3, :3]
        np.testing.assert_allclose(R @ np.swapaxes(R, 1, 2), np.broadcast_to(np.eye(3), R.shape), atol=1e-9)
        assert np.allclose(np.linalg.det(R), 1.0)
        # contacts lie on the surface, on the pads: |y| = width / 2, x = 0, z within the pad range
        assert surface_distance(obj.mesh, g.contacts.reshape(-1, 3)).max() < 1e-6, obj.name
        local = np.einsum("nji,nkj->nki", R, g.contacts - g.poses[:, None, :3, 3])
        np.testing.assert_allclose(np.abs(local[:, :, 1]), np.repeat(g.widths[:, None] / 2, 2, axis=1), atol=1e-6)
        np.testing.assert_allclose(local[:, :, 0], 0.0, atol=1e-6)
        assert local[:, :, 2].min() > -1e-6 and local[:, :, 2].max() < max(PANDA.contact_shifts) + 1e-6
        # fingers (closed on the contacts, 2 mm clearance at the pads) and palm stay outside the solid
        picks = np.unique(np.linspace(0, len(g) - 1, 8).astype(int))
        pts = []
        for i in picks:
            for lo, hi in gripper_boxes(g.widths[i], PANDA, inner_tolerance=0.002):
                local_pts = box_grid(lo, hi)
                pts.append(local_pts @ g.poses[i, :3, :3].T + g.poses[i, :3, 3])
        inside = obj.mesh.contains(np.concatenate(pts))
        assert not inside.any(), f"{obj.name}: {int(inside.sum())} gripper points inside the mesh"


def test_grasps_are_deterministic_and_cached(builtin_small):
    obj = builtin_small[0]
    a = obj.grasps
    b = sample_grasps(obj)
    assert a is b
    fresh = ObjectModel(obj_id=1, name="copy", category="box", instance=0, mesh=obj.mesh.copy())
    c = sample_grasps(fresh, num_points=300)
    d = sample_grasps(fresh, num_points=300)
    assert c is d
    assert len(sample_grasps(fresh, num_points=301)) > 0


def test_huge_object_not_graspable():
    mesh = trimesh.creation.box(extents=[0.3, 0.3, 0.3])
    obj = ObjectModel(obj_id=1, name="crate", category="box", instance=0, mesh=mesh)
    assert len(obj.grasps) == 0
    assert not obj.graspable


def test_graspset_best_and_transformed(builtin_small):
    g = builtin_small.by_name("can_0").grasps
    best = g.best(5)
    assert len(best) == 5
    assert np.all(np.diff(best.scores) <= 0) and best.scores[0] == g.scores.max()
    T = np.eye(4)
    T[:3, :3] = trimesh.transformations.rotation_matrix(0.7, [0, 1, 0])[:3, :3]
    T[:3, 3] = [0.1, -0.2, 0.3]
    moved = g.transformed(T)
    np.testing.assert_allclose(moved.poses[3], T @ g.poses[3])
    np.testing.assert_allclose(moved.contacts[3, 0], T[:3, :3] @ g.contacts[3, 0] + T[:3, 3])
    np.testing.assert_array_equal(moved.widths, g.widths)
    with pytest.raises(ValueError):
        g.poses[0, 0, 0] = 5.0
    assert len(GraspSet.empty()) == 0 and len(GraspSet.empty().best(3)) == 0
    with pytest.raises(ValueError, match="same length"):
        GraspSet(np.zeros((2, 4, 4)), np.zeros(3), np.zeros(2))
