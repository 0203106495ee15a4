"""Viewpoint protocol: geodesic error, accuracies, median, and the (azimuth, elevation, theta) convention."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from simtest.errors import ConfigError
from simtest.geometry import random_rotation, rotation_about
from simtest.metrics import (
    accuracy_at,
    geodesic_error,
    median_error_deg,
    pose_to_viewpoint,
    rotation_errors,
    rotation_to_viewpoint,
    viewpoint_summary,
    viewpoint_to_pose,
    viewpoint_to_rotation,
)
from simtest.metrics.viewpoint import classification_accuracy


def test_geodesic_error_equals_scipy_magnitude_and_broadcasts():
    rng = np.random.default_rng(5)
    P = np.stack([random_rotation(rng) for _ in range(50)])
    G = np.stack([random_rotation(rng) for _ in range(50)])
    expected = Rotation.from_matrix(np.transpose(P, (0, 2, 1)) @ G).magnitude()
    np.testing.assert_allclose(geodesic_error(P, G), expected, atol=1e-7)
    assert geodesic_error(np.eye(3), np.eye(3)) == 0.0
    # Rounding beyond +-1 is clipped, not NaN.
    assert geodesic_error(np.eye(3) * (1 + 1e-12), np.eye(3)) == 0.0
    assert geodesic_error(rotation_about([1, 0, 0], np.pi), np.eye(3)) == pytest.approx(np.pi)


def test_missing_prediction_scores_pi_and_summary():
    gts = [np.eye(3)] * 4
    preds = [rotation_about([0, 0, 1], np.radians(5)), rotation_about([0, 1, 0], np.radians(20)), None,
             rotation_about([1, 0, 0], np.radians(40))]
    e = rotation_errors(preds, gts)
    np.testing.assert_allclose(e, np.radians([5, 20, 180, 40]), atol=1e-9)
    assert accuracy_at(e, np.pi / 6) == 0.5
    assert accuracy_at(e, np.pi / 18) == 0.25
    assert median_error_deg(e) == pytest.approx(30.0)
    s = viewpoint_summary([np.radians(5), None])
    assert s == pytest.approx({"acc_pi_6": 0.5, "acc_pi_18": 0.5, "median_deg": (5 + 180) / 2})
    assert classification_accuracy(["car", "bus"], ["car", "car"]) == 0.5


def test_convention_azimuth_zero_is_the_minus_y_side_and_z_projects_up():
    R, t = viewpoint_to_pose(0.0, 0.0, 0.0, 1.0)
    # Camera centre in the object frame: -R^T t.
    np.testing.assert_allclose(-R.T @ t, [0, -1, 0], atol=1e-12)
    # Object +Z points up in the image (camera -y), object +X to the right (camera +x).
    np.testing.assert_allclose(R @ [0, 0, 1], [0, -1, 0], atol=1e-12)
    np.testing.assert_allclose(R @ [1, 0, 0], [1, 0, 0], atol=1e-12)
    # Azimuth pi/2: camera on the +X side; elevation pi/6: camera above.
    R, t = viewpoint_to_pose(np.pi / 2, np.pi / 6, 0.0, 2.0)
    c = -R.T @ t
    np.testing.assert_allclose(c, 2 * np.array([np.cos(np.pi / 6), 0, np.sin(np.pi / 6)]), atol=1e-12)
    # Positive theta turns the image clockwise: the image of +Z (up) moves towards +x (right).
    R = viewpoint_to_rotation(0.0, 0.0, 0.3)
    up = R @ [0, 0, 1]
    assert up[0] > 0 and up[1] < 0
    assert np.allclose(R @ R.T, np.eye(3)) and np.linalg.det(R) == pytest.approx(1.0)


def test_round_trip():
    rng = np.random.default_rng(7)
    for _ in range(50):
        az, th = rng.uniform(-np.pi, np.pi, 2)
        el = rng.uniform(-np.pi / 2 + 1e-3, np.pi / 2 - 1e-3)
        d = rng.uniform(0.2, 2.0)
        got = pose_to_viewpoint(*viewpoint_to_pose(az, el, th, d))
        np.testing.assert_allclose(got, (az, el, th, d), atol=1e-9)
    for _ in range(50):  # and from rotations to angles and back
        R = random_rotation(rng)
        # (compare matrices: arccos resolves angles only to ~1e-8 rad near 0)
        np.testing.assert_allclose(viewpoint_to_rotation(*rotation_to_viewpoint(R)), R, atol=1e-12)
    # At the pole azimuth is 0 and theta carries the in-plane rotation; the rotation is still exact.
    R = viewpoint_to_rotation(1.0, np.pi / 2, 0.2)
    az, el, th = rotation_to_viewpoint(R)
    assert az == 0.0 and el == pytest.approx(np.pi / 2)
    np.testing.assert_allclose(viewpoint_to_rotation(az, el, th), R, atol=1e-12)


def test_bad_inputs():
    with pytest.raises(ConfigError, match="elevation"):
        viewpoint_to_rotation(0.0, 2.0, 0.0)
    with pytest.raises(ConfigError, match="3 ground-truth"):
        rotation_errors([None], [np.eye(3)] * 3)
    with pytest.raises(ConfigError, match="distance"):
        viewpoint_to_pose(0, 0, 0, 0.0)
