"""The z-buffer rasterizer against analytic depth and a per-triangle brute-force reference."""

from __future__ import annotations

import numpy as np
import pytest
import trimesh

from simtest.errors import ConfigError
from simtest.geometry import rotation_about
from simtest.render.zbuffer import depth_to_distance, rasterize_depth, render_depth

K = np.array([[600.0, 0.0, 319.5], [0.0, 600.0, 239.5], [0.0, 0.0, 1.0]])
SQUARE_F = np.array([[0, 1, 2], [0, 2, 3]])


def _square(half: float, z) -> np.ndarray:
    xy = np.array([[-half, -half], [half, -half], [half, half], [-half, half]])
    zz = z(xy[:, 0], xy[:, 1]) if callable(z) else np.full(4, z)
    return np.column_stack([xy, zz])


def _brute_force(V, F, K, w, h):
    """Per triangle, per pixel: barycentric inside test and perspective-correct 1/z (slow, obvious)."""
    out = np.full((h, w), np.inf)
    uu, vv = np.meshgrid(np.arange(w, dtype=float), np.arange(h, dtype=float))
    for f in F:
        p = V[f]
        q = p @ K.T
        u, v = q[:, 0] / q[:, 2], q[:, 1] / q[:, 2]
        area = (u[1] - u[0]) * (v[2] - v[0]) - (u[2] - u[0]) * (v[1] - v[0])
        if abs(area) < 1e-12:
            continue
        b0 = ((u[1] - uu) * (v[2] - vv) - (u[2] - uu) * (v[1] - vv)) / area
        b1 = ((u[2] - uu) * (v[0] - vv) - (u[0] - uu) * (v[2] - vv)) / area
        b2 = 1 - b0 - b1
        inside = (b0 >= -1e-9) & (b1 >= -1e-9) & (b2 >= -1e-9)
        z = 1.0 / (b0 / p[0, 2] + b1 / p[1, 2] + b2 / p[2, 2])
        out = np.where(inside & (z < out), z, out)
    out[~np.isfinite(out)] = 0
    return out


def test_fronto_parallel_square_has_constant_depth_and_exact_pixel_count():
    depth = rasterize_depth(_square(0.1, 1.0), SQUARE_F, K, 640, 480)
    assert depth.dtype == np.float32 and depth.shape == (480, 640)
    assert set(np.unique(depth)) == {0.0, 1.0}
    # Corners project to u = 319.5 +- 60, v = 239.5 +- 60: pixel centres 260..379 and 180..299.
    rows, cols = np.nonzero(depth)
    assert (cols.min(), cols.max(), rows.min(), rows.max()) == (260, 379, 180, 299)
    assert len(rows) == 120 * 120


def test_tilted_plane_matches_analytic_depth_at_pixel_centres():
    # Plane z = 1 + 0.5 x + 0.2 y; along the ray of pixel (u, v): z = 1 / (1 - 0.5 xn - 0.2 yn).
    V = _square(0.15, lambda x, y: 1.0 + 0.5 * x + 0.2 * y)
    depth = rasterize_depth(V, SQUARE_F, K, 640, 480)
    rows, cols = np.nonzero(depth)
    assert len(rows) > 10000
    xn = (cols - K[0, 2]) / K[0, 0]
    yn = (rows - K[1, 2]) / K[1, 1]
    expected = 1.0 / (1.0 - 0.5 * xn - 0.2 * yn)
    assert np.max(np.abs(depth[rows, cols] - expected)) < 1e-6


def test_nearer_surface_wins_and_empty_pixels_are_zero():
    V = np.vstack([_square(0.1, 1.0), _square(0.02, 0.5)])
    F = np.vstack([SQUARE_F, SQUARE_F + 4])
    depth = rasterize_depth(V, F, K, 640, 480)
    assert depth[239, 319] == pytest.approx(0.5)
    assert depth[185, 265] == pytest.approx(1.0)
    assert depth[0, 0] == 0.0
    # Order of the faces does not matter.
    assert np.array_equal(depth, rasterize_depth(V, F[::-1], K, 640, 480))


def test_matches_brute_force_reference_on_a_rotated_mesh():
    mesh = trimesh.creation.cylinder(radius=0.04, height=0.1, sections=24)
    R = rotation_about(np.array([1.0, 2.0, 0.5]), 0.9)
    Ks = np.array([[80.0, 0.0, 31.5], [0.0, 80.0, 23.5], [0.0, 0.0, 1.0]])
    V = mesh.vertices @ R.T + np.array([0.01, -0.005, 0.3])
    fast = rasterize_depth(V, mesh.faces, Ks, 64, 48)
    slow = _brute_force(V, mesh.faces, Ks, 64, 48)
    assert np.array_equal(fast > 0, slow > 0)
    assert np.max(np.abs(fast - slow)) < 1e-6
    # Small batches give the same image.
    assert np.array_equal(fast, rasterize_depth(V, mesh.faces, Ks, 64, 48, max_pairs=7))


def test_render_depth_places_the_model_and_skips_triangles_behind_the_camera():
    box = trimesh.creation.box(extents=(0.1, 0.1, 0.1))
    depth = render_depth(box.vertices, box.faces, np.eye(3), [0, 0, 0.5], K, 640, 480)
    assert depth[239, 319] == pytest.approx(0.45)
    behind = render_depth(box.vertices, box.faces, np.eye(3), [0, 0, -0.5], K, 640, 480)
    assert not behind.any()


def test_depth_to_distance_is_ray_length():
    depth = np.zeros((480, 640), dtype=np.float32)
    depth[239, 319] = 1.0
    depth[0, 0] = 2.0
    dist = depth_to_distance(depth, K)
    xn, yn = (0 - 319.5) / 600, (0 - 239.5) / 600
    assert dist[0, 0] == pytest.approx(2.0 * np.sqrt(xn**2 + yn**2 + 1))
    assert dist[239, 319] == pytest.approx(1.0 * np.sqrt((0.5 / 600) ** 2 * 2 + 1))
    assert dist[10, 10] == 0.0


def test_bad_inputs_name_the_value():
    with pytest.raises(ConfigError, match="shape"):
        rasterize_depth(np.zeros((4, 2)), SQUARE_F, K, 10, 10)
    with pytest.raises(ConfigError, match="5"):
        rasterize_depth(_square(0.1, 1.0), np.array([[0, 1, 5]]), K, 10, 10)
    with pytest.raises(ConfigError, match="0x10"):
        rasterize_depth(_square(0.1, 1.0), SQUARE_F, K, 0, 10)
