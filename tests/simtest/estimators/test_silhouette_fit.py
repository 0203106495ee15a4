"""Silhouette alignment of pose estimates: the exact outline it compares, and fits that recover a moved pose."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from simtest.errors import ConfigError
from simtest.estimators.silhouette import cell_coverage_mask, fit_translation, soft_iou
from simtest.objects import load_object_set
from simtest.render.silhouette import object_silhouette
from simtest.render.zbuffer import rasterize_depth

K = np.array([[300.0, 0.0, 80.0], [0.0, 300.0, 60.0], [0.0, 0.0, 1.0]])
W, H = 160, 128
R0 = cv2.Rodrigues(np.array([[0.9], [-0.4], [0.3]]))[0]
T0 = np.array([0.01, -0.005, 0.55])


@pytest.fixture(scope="module")
def objects():
    return load_object_set("builtin-small")


def _moved(t: np.ndarray, scale: float, du: float, dv: float) -> np.ndarray:
    """``t`` with its depth times ``scale`` and its image position moved by ``(du, dv)`` pixels."""
    u, v = (K[:2] @ (t / t[2]))
    z = t[2] * scale
    return z * (np.linalg.inv(K) @ np.array([u + du, v + dv, 1.0]))


def test_object_silhouette_is_the_zbuffer_coverage(objects):
    """The annotator's silhouette fill equals the pixels the independent z-buffer rasterizer covers."""
    for obj in objects:
        sil = object_silhouette(obj, R0, T0, K, W, H)
        cover = rasterize_depth(obj.vertices @ R0.T + T0, obj.faces, K, W, H) > 0
        assert cover.sum() > 300, obj.name
        assert (sil != cover).sum() <= 0.01 * cover.sum(), (obj.name, int((sil != cover).sum()), int(cover.sum()))


def test_a_silhouette_past_the_image_edge_is_clipped(objects):
    obj = objects.get(7)
    t = _moved(T0, 1.0, 75.0, 0.0)  # the object's centre near the right edge
    sil = object_silhouette(obj, R0, t, K, W, H)
    assert sil.shape == (H, W) and sil[:, -1].any() and not sil[:, :40].any()


@pytest.mark.parametrize("obj_id", [1, 7, 13, 22])
def test_the_fit_recovers_depth_and_image_position(objects, obj_id):
    obj = objects.get(obj_id)
    target = object_silhouette(obj, R0, T0, K, W, H).astype(np.float64)
    start = _moved(T0, 1.06, 2.5, -1.5)
    fit = fit_translation(obj, R0, start, K, target, np.ones((H, W), bool))
    assert fit.applied and fit.iou_after > 0.97 > fit.iou_before
    assert abs(fit.t[2] / T0[2] - 1.0) < 0.006, fit
    assert np.linalg.norm(fit.t - T0) < 0.004, fit
    np.testing.assert_array_equal(fit.R, R0)  # no rotation steps asked for


def test_rotation_steps_bring_a_turned_pose_back(objects):
    obj = objects.get(13)
    target = object_silhouette(obj, R0, T0, K, W, H).astype(np.float64)
    turn = cv2.Rodrigues(np.radians([[3.0], [-2.0], [2.0]]))[0]
    start_R, start_t = turn @ R0, _moved(T0, 0.96, -1.0, 1.0)
    fit = fit_translation(obj, start_R, start_t, K, target, np.ones((H, W), bool), step_deg=2.0)
    err = lambda R, t: float(np.linalg.norm((obj.vertices @ R.T + t) - (obj.vertices @ R0.T + T0), axis=1).mean())
    assert fit.iou_after > 0.96
    assert err(fit.R, fit.t) < 0.3 * err(start_R, start_t), (err(fit.R, fit.t), err(start_R, start_t))


def test_pixels_hidden_by_other_objects_do_not_count(objects):
    """An occluder known to the estimator (another detection) hides the object's left part: the visible mask
    is smaller, but with those pixels out of ``valid`` the fit still finds the true depth. Counted as
    background, they pull the silhouette smaller (farther)."""
    obj = objects.get(7)
    sil = object_silhouette(obj, R0, T0, K, W, H)
    xs = np.flatnonzero(sil.any(0))
    hidden = np.zeros_like(sil)
    hidden[:, : xs[0] + int(0.4 * (xs[-1] - xs[0]))] = True
    visible = (sil & ~hidden).astype(np.float64)
    start = _moved(T0, 1.05, 0.0, 0.0)
    fit = fit_translation(obj, R0, start, K, visible, ~hidden)
    assert abs(fit.t[2] / T0[2] - 1.0) < 0.01, fit
    naive = fit_translation(obj, R0, start, K, visible, np.ones_like(sil))
    assert naive.t[2] > fit.t[2] + 0.01


@pytest.mark.parametrize("obj_id", [1, 7, 13])
def test_a_cell_mask_is_compared_through_the_cell_rule(objects, obj_id):
    """A mask network trained on stride-4 cells covered to 30 % predicts a grown outline; compared through
    :func:`cell_coverage_mask` the fit finds the true depth (on average over where the cell grid falls on
    the object; one placement is off by the grid's quantisation), compared as a pixel mask it comes out too
    near."""
    obj = objects.get(obj_id)
    cell_fit, plain_fit = [], []
    for du, dv in [(0, 0), (1, 1.5), (2, 3), (3, 0.5), (0.5, 2.5), (2.5, 1)]:
        t = _moved(T0, 1.0, du, dv)
        sil = object_silhouette(obj, R0, t, K, W, H)
        cells = sil.reshape(H // 4, 4, W // 4, 4).mean(axis=(1, 3)) >= 0.3
        prob = cv2.resize(cells.astype(np.float32), (W, H), interpolation=cv2.INTER_LINEAR)
        assert cell_coverage_mask(sil, 4, 0.3).sum() > sil.sum()  # the cell rule grows the outline
        start = _moved(t, 1.04, 1.0, 1.0)
        cell_fit.append(fit_translation(obj, R0, start, K, prob, np.ones_like(sil), cells=(4, 0.3)).t[2] / t[2])
        plain_fit.append(fit_translation(obj, R0, start, K, prob, np.ones_like(sil)).t[2] / t[2])
    assert abs(np.mean(cell_fit) - 1.0) < 0.01 and max(abs(np.subtract(cell_fit, 1.0))) < 0.025, cell_fit
    assert np.mean(plain_fit) < 0.985, plain_fit


def test_soft_iou_and_bad_input():
    a = np.zeros((4, 4), bool)
    a[:2] = True
    assert soft_iou(a, a.astype(float), np.ones_like(a)) == 1.0
    assert soft_iou(a, np.zeros((4, 4)), np.ones_like(a)) == 0.0
    assert soft_iou(np.zeros_like(a), np.zeros((4, 4)), np.ones_like(a)) == 0.0
    obj = load_object_set("builtin-small").get(1)
    with pytest.raises(ConfigError, match="same"):
        fit_translation(obj, R0, T0, K, np.zeros((4, 4)), np.ones((5, 4), bool))
    with pytest.raises(ConfigError, match="max_scale"):
        fit_translation(obj, R0, T0, K, np.zeros((4, 4)), np.ones((4, 4), bool), max_scale=1.5)
