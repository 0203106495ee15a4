"""Declared symmetries map each mesh onto itself; wrong ones do not."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from simtest.geometry import rotation_about
from simtest.objects.builtin import box_symmetries

TOL = 1e-3  # metres


def surface_deviation(obj, T: np.ndarray, n: int = 400) -> float:
    """Largest distance (m) from transformed surface samples to the mesh surface."""
    pts = obj.surface_points[:n]
    moved = pts @ T[:3, :3].T + T[:3, 3]
    _, dist, _ = trimesh.proximity.closest_point(obj.mesh, moved)
    return float(dist.max())


def declared_transforms(obj) -> list[np.ndarray]:
    """Every discrete symmetry and a few rotations of each continuous one."""
    out = list(obj.symmetries_discrete)
    for sym in obj.symmetries_continuous:
        for angle in (0.37, 1.9, np.pi, 4.4):
            T = np.eye(4)
            R = rotation_about(np.asarray(sym.axis), angle)
            T[:3, :3] = R
            T[:3, 3] = np.asarray(sym.offset) - R @ np.asarray(sym.offset)
            out.append(T)
    return out


def test_declared_symmetries_map_mesh_onto_itself(builtin):
    checked = 0
    for obj in builtin:
        for T in declared_transforms(obj):
            dev = surface_deviation(obj, T)
            assert dev < TOL, f"{obj.name}: symmetry deviates by {dev * 1000:.2f} mm"
            checked += 1
    assert checked > 50


def test_symmetry_transforms_include_declared(builtin):
    box = builtin.by_name("box_2")
    Ts = box.symmetry_transforms()
    assert len(Ts) == 8 and np.allclose(Ts[0], np.eye(4))
    can = builtin.by_name("can_0")
    # Continuous about z (315 steps) combined with the end-swapping half turn about x.
    assert len(can.symmetry_transforms()) == 2 * int(np.ceil(np.pi / 0.01))


@pytest.mark.parametrize("name,axis,angle", [
    ("mug_0", (0, 0, 1), np.pi),        # the handle moves
    ("mug_0", (0, 0, 1), 0.5),
    ("box_0", (0, 0, 1), np.pi / 2),    # not square in cross-section
    ("banana_0", (1, 0, 0), np.pi),
    ("drill_0", (0, 0, 1), np.pi),
    ("can_0", (1, 0, 0), np.pi / 2),    # lying on its side is not the same
])
def test_wrong_symmetry_fails(builtin, name, axis, angle):
    T = np.eye(4)
    T[:3, :3] = rotation_about(np.asarray(axis, dtype=float), angle)
    assert surface_deviation(builtin.by_name(name), T) > 3 * TOL


def test_symmetry_labels(builtin):
    assert builtin.by_name("mug_0").symmetry_label() == "none"
    assert builtin.by_name("can_0").symmetry_label() == "continuous(z)+discrete(1)"
    assert builtin.by_name("bottle_0").symmetry_label() == "continuous(z)"
    assert builtin.by_name("box_0").symmetry_label() == "discrete(3)"
    assert builtin.by_name("box_2").symmetry_label() == "discrete(7)"
    for name in ("can_0", "bottle_1", "bowl_2", "cup_0", "marker_2"):
        (sym,) = builtin.by_name(name).symmetries_continuous
        assert sym.axis == (0.0, 0.0, 1.0) and sym.offset == (0.0, 0.0, 0.0)


def test_box_symmetry_groups():
    assert len(box_symmetries(np.array([0.1, 0.2, 0.3]))) == 3
    assert len(box_symmetries(np.array([0.1, 0.1, 0.3]))) == 7
    assert len(box_symmetries(np.array([0.1, 0.1, 0.1]))) == 23
