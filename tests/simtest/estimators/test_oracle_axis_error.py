"""The oracle's exact error along one axis: where it moves the pose, its sign, and the options it refuses."""

from __future__ import annotations

import numpy as np
import pytest

from simtest.errors import ConfigError
from simtest.estimators.base import Observation
from simtest.estimators.oracle import ERROR_AXES, OracleEstimator, axis_angle_matrix, axis_error

R_G = axis_angle_matrix(np.array([0.0, 0.6, 0.8]), 0.7)
T_G = np.array([0.1, -0.05, 0.6])


def test_translation_axes_move_along_the_object_axes_and_the_ray():
    for k, axis in enumerate(("t_x", "t_y", "t_z")):
        R, t = axis_error(R_G, T_G, axis, 20.0)
        assert np.allclose(R, R_G) and np.allclose(t - T_G, 0.02 * R_G[:, k])
    R, t = axis_error(R_G, T_G, "t_ray", -30.0)
    assert np.allclose(t, T_G * (1 - 0.03 / np.linalg.norm(T_G)))  # nearer the camera, on the same ray


def test_rotation_axes_turn_about_the_object_axes():
    R, t = axis_error(R_G, T_G, "r_z", 90.0)
    assert np.allclose(t, T_G)
    assert np.allclose(R[:, 2], R_G[:, 2])  # the object's z stays, x turns into y
    assert np.allclose(R[:, 0], R_G[:, 1])
    geodesic = np.degrees(np.arccos((np.trace(R_G.T @ R) - 1) / 2))
    assert geodesic == pytest.approx(90.0)


def _observation(scene_id: int) -> Observation:
    return Observation(rgb=None, depth=None, K=np.eye(3), width=64, height=48, objects=None, target_obj_ids=(1,),
                       gt_poses=((R_G, T_G),), scene_id=scene_id, im_id=0)


def test_oracle_applies_the_error_with_a_seeded_sign():
    signs = []
    for scene in range(12):
        est = OracleEstimator(error_axis="t_x", error=10.0).estimate(_observation(scene))[0]
        d = (est.t - T_G) @ R_G[:, 0]
        assert abs(d) == pytest.approx(0.01)
        signs.append(np.sign(d))
        again = OracleEstimator(error_axis="t_x", error=10.0).estimate(_observation(scene))[0]
        assert np.array_equal(est.t, again.t)
    assert set(signs) == {-1.0, 1.0}
    plus = OracleEstimator(error_axis="r_x", error=5.0, error_sign="+").estimate(_observation(0))[0]
    assert np.allclose(plus.R, R_G @ axis_angle_matrix(np.array([1.0, 0, 0]), np.radians(5.0)))


def test_bad_options_are_named():
    with pytest.raises(ConfigError, match="error_axis must be one of"):
        OracleEstimator(error_axis="x")
    with pytest.raises(ConfigError, match="error must be >= 0"):
        OracleEstimator(error_axis="t_x", error=-1.0)
    with pytest.raises(ConfigError, match="error_sign"):
        OracleEstimator(error_axis="t_x", error=1.0, error_sign="up")
    assert len(ERROR_AXES) == 7
