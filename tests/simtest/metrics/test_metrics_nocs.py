"""Category-level (NOCS) metrics: rotation / translation errors, n deg m cm, 3D IoU, Chamfer distance."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from simtest.errors import ConfigError
from simtest.geometry import random_rotation, rotation_about
from simtest.metrics.nocs import remove_scale
from simtest.metrics import (
    chamfer_distance,
    iou_3d,
    iou_3d_legacy,
    iou_accuracy,
    n_deg_m_cm,
    n_deg_m_cm_accuracy,
    rotation_error,
    rotation_error_deg,
    translation_error_cm,
)
from simtest.metrics.nocs import is_symmetric_category


def _sRT(R=np.eye(3), t=(0.0, 0.0, 0.7), s=1.0):
    T = np.eye(4)
    T[:3, :3] = s * np.asarray(R)
    T[:3, 3] = t
    return T


CUBE = (0.1, 0.1, 0.1)


def test_iou_counter_example_correct_and_legacy():
    # Two 10 cm cubes 0.7 m in front of the camera, 2 cm apart along x.
    a, b = _sRT(), _sRT(t=(0.02, 0.0, 0.7))
    assert iou_3d(a, b, CUBE, CUBE) == pytest.approx(0.08 / 0.12)  # 0.667
    # The reference's axis-mixing computation gives 0.947 here.
    assert iou_3d_legacy(a, b, CUBE, CUBE) == pytest.approx(0.947, abs=5e-4)


def test_iou_identical_disjoint_touching_and_scaled():
    a = _sRT(R=rotation_about([1, 2, 3], 0.4))
    assert iou_3d(a, a, CUBE, CUBE) == pytest.approx(1.0)
    assert iou_3d_legacy(_sRT(), _sRT(), CUBE, CUBE) == pytest.approx(1.0)
    assert iou_3d(_sRT(), _sRT(t=(0.5, 0, 0.7)), CUBE, CUBE) == 0.0
    assert iou_3d(_sRT(), _sRT(t=(0.1, 0, 0.7)), CUBE, CUBE) == 0.0  # sharing a face only
    # Scale lives in sRT: s = 0.5 with extents 0.2 is the same box as s = 1 with extents 0.1.
    b = _sRT(t=(0.02, 0.0, 0.7), s=0.5)
    assert iou_3d(_sRT(), b, CUBE, (0.2, 0.2, 0.2)) == pytest.approx(0.08 / 0.12)


def test_iou_of_a_cube_and_its_45_degree_turn_is_one_over_sqrt2():
    # Cross-section: a square and the same square turned by 45 deg overlap in a regular octagon.
    a, b = _sRT(), _sRT(R=rotation_about([0, 0, 1], np.pi / 4))
    assert iou_3d(a, b, CUBE, CUBE) == pytest.approx(1 / np.sqrt(2))


def test_iou_matches_mesh_boolean_on_random_boxes():
    rng = np.random.default_rng(11)
    for _ in range(4):
        s1, s2 = rng.uniform(0.05, 0.15, 3), rng.uniform(0.05, 0.15, 3)
        T1 = _sRT(R=random_rotation(rng), t=rng.normal(scale=0.02, size=3))
        T2 = _sRT(R=random_rotation(rng), t=rng.normal(scale=0.02, size=3))
        b1 = trimesh.creation.box(extents=s1, transform=T1)
        b2 = trimesh.creation.box(extents=s2, transform=T2)
        inter = b1.intersection(b2)
        v = inter.volume if len(inter.faces) else 0.0
        expected = v / (np.prod(s1) + np.prod(s2) - v)
        # (the mesh boolean works at ~1e-8 relative precision; the polytope volume is exact to rounding)
        assert iou_3d(T1, T2, s1, s2) == pytest.approx(expected, abs=1e-6)


def test_symmetric_iou_maximises_over_rotations_about_the_axis():
    size = (0.1, 0.05, 0.08)
    a, b = _sRT(), _sRT(R=rotation_about([0, 0, 1], np.pi / 2))
    # Turned by 90 deg about z: overlap 0.05 x 0.05 x 0.08 out of two 0.1 x 0.05 x 0.08 boxes.
    assert iou_3d(a, b, size, size) == pytest.approx(1 / 3)
    # 90 deg is one of the 20 steps (18 deg each) about z, the default axis.
    assert iou_3d(a, b, size, size, symmetric=True) == pytest.approx(1.0)
    # About y (the NOCS reference's axis) no step undoes a turn about z.
    assert iou_3d(a, b, size, size, symmetric=True, sym_axis=(0, 1, 0)) < 0.5
    assert iou_3d_legacy(a, b, size, size, symmetric=True, sym_axis=(0, 0, 1)) == pytest.approx(1.0)


def test_rotation_error_removes_scale_and_handles_symmetry():
    R = rotation_about([0, 0, 1], np.radians(30))
    assert rotation_error_deg(3.0 * R, np.eye(3)) == pytest.approx(30.0)
    # Rotation about the symmetry axis is free; about another axis it counts.
    assert rotation_error(_sRT(R, s=2.0), _sRT(), symmetric=True) == pytest.approx(0.0, abs=1e-7)
    Ry = rotation_about([0, 1, 0], np.radians(30))
    assert rotation_error_deg(Ry, np.eye(3), symmetric=True) == pytest.approx(30.0)
    assert rotation_error_deg(Ry, np.eye(3), symmetric=True, sym_axis=(0, 1, 0)) == pytest.approx(0.0, abs=1e-5)
    # Values a hair outside [-1, 1] are clipped instead of giving NaN: a rotation against itself gives a cosine
    # of 1 +- a few ulp (which side depends on the rotation and the platform's rounding).
    rng = np.random.default_rng(0)
    over = 0
    for _ in range(100):
        Q = random_rotation(rng)
        Qs = remove_scale(Q)
        over += 0.5 * (np.trace(Qs @ Qs.T) - 1.0) > 1.0
        assert 0.0 <= rotation_error(Q, Q) < 1e-7
        assert 0.0 <= rotation_error(Q, Q, symmetric=True) < 1e-7
    assert over > 0  # the clipping was needed
    assert is_symmetric_category("can") and is_symmetric_category("mug", handle_visible=False)
    assert not is_symmetric_category("mug") and not is_symmetric_category("laptop")


def test_translation_error_and_inclusive_n_deg_m_cm():
    assert translation_error_cm([0, 0, 0.7], [0.0, 0.02, 0.7]) == pytest.approx(2.0)
    assert translation_error_cm(_sRT(t=(0, 0, 0.5)), _sRT(t=(0, 0, 0.55))) == pytest.approx(5.0)
    assert n_deg_m_cm(5.0, 2.0, 5, 2)
    assert not n_deg_m_cm(5.0 + 1e-9, 2.0, 5, 2)
    assert not n_deg_m_cm(5.0, 2.0 + 1e-9, 5, 2)
    acc = n_deg_m_cm_accuracy([5.0, 10.0, 4.0, 12.0], [2.0, 5.0, 5.0, 1.0])
    assert acc == {"5deg2cm": 0.25, "5deg5cm": 0.5, "10deg2cm": 0.25, "10deg5cm": 0.75}
    assert iou_accuracy([0.25, 0.5, 0.74, 0.8]) == {"iou25": 1.0, "iou50": 0.75, "iou75": 0.25}


def test_chamfer_distance_hand_computed():
    a = np.array([[0.0, 0.0, 0.0]])
    b = np.array([[1.0, 0.0, 0.0], [0.0, 2.0, 0.0]])
    # a -> b: 1; b -> a: mean(1, 2) = 1.5; mean of both directions: 1.25.
    assert chamfer_distance(a, b) == pytest.approx(1.25)
    assert chamfer_distance(b, a) == pytest.approx(1.25)
    assert chamfer_distance(a, b, squared=True) == pytest.approx((1.0 + 2.5) / 2)
    assert chamfer_distance(b, b) == 0.0


def test_bad_inputs():
    with pytest.raises(ConfigError, match="size_1"):
        iou_3d(_sRT(), _sRT(), (0.1, -0.1, 0.1), CUBE)
    with pytest.raises(ConfigError, match="sRT_2"):
        iou_3d(_sRT(), np.eye(3), CUBE, CUBE)
    with pytest.raises(ConfigError, match="sym_axis"):
        rotation_error(np.eye(3), np.eye(3), symmetric=True, sym_axis=(0, 0, 0))
    with pytest.raises(ConfigError, match="3 rotation and 2"):
        n_deg_m_cm_accuracy([1, 2, 3], [1, 2])
