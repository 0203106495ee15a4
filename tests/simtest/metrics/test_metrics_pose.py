"""Instance-level pose errors against hand-computed values and against each other."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh
from scipy.spatial.transform import Rotation

from simtest.errors import ConfigError
from simtest.geometry import random_rotation, rotation_about
from simtest.metrics import add, add_01d, add_s_or_add, adi, mspd, mssd, re, rotation_error_rad, te, vsd
from simtest.metrics.pose import as_symmetries, re_sym, vsd_from_depth
from simtest.objects import ContinuousSymmetry, ObjectModel
from simtest.render.zbuffer import render_depth

K = np.array([[600.0, 0.0, 319.5], [0.0, 600.0, 239.5], [0.0, 0.0, 1.0]])
I3 = np.eye(3)
T0 = np.array([0.0, 0.0, 0.6])


@pytest.fixture(scope="module")
def can() -> ObjectModel:
    mesh = trimesh.creation.cylinder(radius=0.03, height=0.1, sections=64)
    return ObjectModel(1, "cyl", "can", 0, mesh, symmetries_continuous=(ContinuousSymmetry((0, 0, 1)),))


@pytest.fixture(scope="module")
def box() -> ObjectModel:
    return ObjectModel(2, "box", "box", 0, trimesh.creation.box(extents=(0.1, 0.06, 0.04)))


def test_pure_translation_gives_add_te_mssd_equal_to_the_offset(box):
    pts = box.vertices
    t_e = T0 + [0.01, 0.0, 0.0]
    assert add(I3, t_e, I3, T0, pts) == pytest.approx(0.01)
    assert te(t_e, T0) == pytest.approx(0.01)
    assert mssd(I3, t_e, I3, T0, pts) == pytest.approx(0.01)
    assert re(I3, I3) == 0.0


def test_mspd_of_a_lateral_shift_is_its_projection(box):
    pts = box.vertices
    t_e = T0 + [0.01, 0.0, 0.0]
    # A lateral shift dx at depth z moves every projection by fx dx / z for points at depth z.
    z = T0[2] + pts[:, 2]
    expected = np.max(600.0 * 0.01 / z)
    assert mspd(I3, t_e, I3, T0, K, pts) == pytest.approx(expected)
    # BOP normalises to a 640 px wide image: a 1280 px image halves the error.
    assert mspd(I3, t_e, I3, T0, K, pts, image_width=1280) == pytest.approx(expected / 2)


def test_rotation_error_matches_scipy_and_degrees():
    rng = np.random.default_rng(0)
    for _ in range(20):
        R1, R2 = random_rotation(rng), random_rotation(rng)
        mag = Rotation.from_matrix(R1 @ R2.T).magnitude()
        assert rotation_error_rad(R1, R2) == pytest.approx(mag, abs=1e-7)
        assert re(R1, R2) == pytest.approx(np.degrees(mag), abs=1e-5)
    assert re(rotation_about([0, 0, 1], np.pi), I3) == pytest.approx(180.0)


def test_rotation_about_the_symmetry_axis(can):
    pts = can.vertices
    syms = can.symmetry_transforms()
    assert syms.shape == (315, 4, 4) and np.allclose(syms[0], np.eye(4))
    # Halfway between two cylinder facets and two symmetry steps: the worst case for both discretisations.
    R_e = rotation_about([0, 0, 1], 0.7)
    e_add = add(R_e, T0, I3, T0, pts)
    assert e_add > 0.01
    # ADD-S: the rotated polygon's vertices are within a chord of the original ones (64 sections).
    assert adi(R_e, T0, I3, T0, pts) < 2 * 0.03 * np.sin(np.pi / 64)
    # MSSD: the nearest of 315 symmetry steps is at most pi/315 away -> r * pi / 315 on the rim.
    assert mssd(R_e, T0, I3, T0, pts, syms) <= 0.03 * np.pi / 315 + 1e-12
    assert mspd(R_e, T0, I3, T0, K, pts, syms) < 0.5
    # With only the identity, MSSD is the largest point displacement >= ADD.
    assert mssd(R_e, T0, I3, T0, pts) >= e_add
    assert add_s_or_add(can, R_e, T0, I3, T0) == adi(R_e, T0, I3, T0, pts)
    assert add_01d(can, R_e, T0, I3, T0)


def test_re_sym_is_the_smallest_rotation_error_over_the_symmetries(can, box):
    syms = can.symmetry_transforms()
    R_e = rotation_about([0, 0, 1], 0.7)  # about the can's axis: equivalent up to one discretisation step
    assert re(R_e, I3) == pytest.approx(np.degrees(0.7)) and re_sym(R_e, I3, syms) <= 180.0 / 315 + 1e-9
    tilt = rotation_about([1, 0, 0], 0.3) @ R_e  # a tilt of the axis is not a symmetry
    assert re_sym(tilt, I3, syms) == pytest.approx(np.degrees(0.3), abs=180.0 / 315)
    rng = np.random.default_rng(3)
    for _ in range(5):  # no symmetries: re_sym is re; (S, 3, 3) rotations work as (S, 4, 4) transforms
        R1, R2 = random_rotation(rng), random_rotation(rng)
        assert re_sym(R1, R2, box.symmetry_transforms()) == pytest.approx(re(R1, R2), abs=1e-9)
        assert re_sym(R1, R2, syms[:, :3, :3]) == re_sym(R1, R2, syms)
    with pytest.raises(ConfigError, match=r"syms must be \(S, 4, 4\) or \(S, 3, 3\)"):
        re_sym(I3, I3, np.eye(4))


def test_consistency_on_random_poses(box):
    rng = np.random.default_rng(1)
    pts = box.vertices
    for _ in range(10):
        R_e, R_g = random_rotation(rng), random_rotation(rng)
        t_e, t_g = T0 + rng.normal(scale=0.02, size=3), T0
        a, s, m = add(R_e, t_e, R_g, t_g, pts), adi(R_e, t_e, R_g, t_g, pts), mssd(R_e, t_e, R_g, t_g, pts)
        assert s <= a + 1e-12
        assert m >= a - 1e-12
        # Identity symmetry given explicitly (array or BOP dicts) changes nothing.
        assert mssd(R_e, t_e, R_g, t_g, pts, [{"R": I3, "t": np.zeros(3)}]) == pytest.approx(m)


def test_add_01d_uses_add_for_asymmetric_objects(box):
    d = box.diameter
    assert add_01d(box, I3, T0 + [0.09 * d, 0, 0], I3, T0)
    assert not add_01d(box, I3, T0 + [0.11 * d, 0, 0], I3, T0)
    R_e = rotation_about([0, 0, 1], np.pi)  # the box has a 2-fold symmetry, but none is declared
    assert add_s_or_add(box, R_e, T0, I3, T0) == add(R_e, T0, I3, T0, box.vertices) > 0.02


def test_vsd_identical_poses_is_zero_and_disjoint_renders_is_one(box):
    depth_test = render_depth(box.vertices, box.faces, I3, T0, K, 640, 480)
    taus = [0.05, 0.2]
    e = vsd(I3, T0, I3, T0, depth_test, K, box, 0.015, taus, box.diameter)
    assert np.array_equal(e, [0.0, 0.0])
    far = T0 + [0.3, 0.0, 0.0]  # entirely to the side: no common pixel
    assert np.array_equal(vsd(I3, far, I3, T0, depth_test, K, (box.vertices, box.faces), 0.015, taus,
                              box.diameter), [1.0, 1.0])
    # Nothing rendered at all (both behind the camera): 1 by definition.
    assert np.array_equal(vsd(I3, -T0, I3, -T0, depth_test, K, box, 0.015, taus, box.diameter), [1.0, 1.0])


def test_vsd_depth_shift_hand_computed():
    # Three pixels rendered by both poses, estimate 3 cm farther; test depth empty (all visible).
    depth_gt = np.zeros((1, 4), dtype=np.float32)
    depth_gt[0, :3] = 1.0
    depth_est = np.zeros((1, 4), dtype=np.float32)
    depth_est[0, 1:] = 1.03
    Kc = np.array([[1e6, 0, 1.5], [0, 1e6, 0.0], [0, 0, 1]])  # long focal length: distance ~ depth
    e = vsd_from_depth(depth_est, depth_gt, np.zeros((1, 4)), Kc, 0.015, [0.2, 0.4], diameter=0.1)
    # union = 4 pixels, intersection = 2 with |diff|/d = 0.3: tau 0.2 -> (2 + 2) / 4, tau 0.4 -> (0 + 2) / 4
    assert e == pytest.approx([1.0, 0.5])
    # An occluder at 0.5 m in front of the GT pixel 0 hides it (0.5 + delta < 1): union shrinks to 3.
    test = np.zeros((1, 4))
    test[0, 0] = 0.5
    e = vsd_from_depth(depth_est, depth_gt, test, Kc, 0.015, [0.4], diameter=0.1)
    assert e == pytest.approx([1.0 / 3.0])
    e_lin = vsd_from_depth(depth_est, depth_gt, np.zeros((1, 4)), Kc, 0.015, [0.6], 0.1, cost_type="tlinear")
    assert e_lin == pytest.approx([(2 * 0.5 + 2) / 4], rel=1e-5)


def test_bad_inputs_raise_config_error(box):
    with pytest.raises(ConfigError, match="R_e"):
        add(np.eye(2), T0, I3, T0, box.vertices)
    with pytest.raises(ConfigError, match="t_g"):
        add(I3, T0, I3, [0, 0], box.vertices)
    with pytest.raises(ConfigError, match="pts"):
        add(I3, T0, I3, T0, np.zeros((0, 3)))
    with pytest.raises(ConfigError, match="cost_type"):
        vsd(I3, T0, I3, T0, np.zeros((4, 4)), K, box, 0.015, [0.1], 0.1, cost_type="linear")
    with pytest.raises(ConfigError, match="symmetries"):
        as_symmetries(np.zeros((3, 3, 3)))


def test_vectorised_mssd_and_mspd_equal_a_loop_over_symmetries(can):
    rng = np.random.default_rng(2)
    pts, syms = can.vertices, can.symmetry_transforms()

    def proj(p):
        q = p @ K.T
        return q[:, :2] / q[:, 2:]

    for i in range(6):
        R_g = random_rotation(rng)
        R_e = R_g @ syms[rng.integers(len(syms)), :3, :3] if i % 2 else random_rotation(rng)
        t_e = T0 + rng.normal(scale=0.005 * (i % 3), size=3)
        posed = [pts @ (R_g @ s[:3, :3]).T + R_g @ s[:3, 3] + T0 for s in syms]
        pe = pts @ R_e.T + t_e
        ref_mssd = min(np.linalg.norm(pe - p, axis=1).max() for p in posed)
        ref_mspd = min(np.linalg.norm(proj(pe) - proj(p), axis=1).max() for p in posed)
        assert mssd(R_e, t_e, R_g, T0, pts, syms) == pytest.approx(ref_mssd, abs=1e-12)
        assert mspd(R_e, t_e, R_g, T0, K, pts, syms) == pytest.approx(ref_mspd, abs=1e-9)
