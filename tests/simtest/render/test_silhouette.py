"""The amodal silhouette fill (``rasterize_silhouette``) against pixel centres tested one by one."""

from __future__ import annotations

import numpy as np
import pytest

from simtest.render.silhouette import rasterize_silhouette


def _inside(uv: np.ndarray, tris: np.ndarray, width: int, height: int) -> np.ndarray:
    """(height, width) bool: pixel centres (x, y) strictly inside any triangle (brute force, edge functions)."""
    ys, xs = np.mgrid[0:height, 0:width]
    out = np.zeros((height, width), dtype=bool)
    for tri in tris:
        a, b, c = uv[tri]
        e = [(q[0] - p[0]) * (ys - p[1]) - (q[1] - p[1]) * (xs - p[0]) for p, q in ((a, b), (b, c), (c, a))]
        out |= ((e[0] > 0) & (e[1] > 0) & (e[2] > 0)) | ((e[0] < 0) & (e[1] < 0) & (e[2] < 0))
    return out


def _canvas(mask: np.ndarray, origin: tuple[int, int], width: int, height: int) -> np.ndarray:
    x0, y0 = origin
    out = np.zeros((height, width), dtype=bool)
    out[y0:y0 + mask.shape[0], x0:x0 + mask.shape[1]] = mask
    return out


# Vertices off the pixel grid (no pixel centre on an edge), all triangles with the same 2D orientation.
UV = np.array([[3.3, 2.7], [27.6, 5.2], [12.4, 21.9], [30.1, 24.6], [5.2, 18.3]])
QUAD = np.array([[0, 1, 2], [1, 3, 2]])  # two triangles sharing the edge 1-2


@pytest.mark.parametrize("tris", [QUAD[:1], QUAD, np.array([[0, 1, 2], [0, 2, 4]])], ids=["one", "quad", "fan"])
def test_fill_is_the_union_of_the_triangles_pixel_centres(tris):
    mask, origin = rasterize_silhouette(UV, tris)
    np.testing.assert_array_equal(_canvas(mask, origin, 40, 32), _inside(UV, tris, 40, 32))


@pytest.mark.parametrize("copies", [1, 2**14 - 1, 2**14, 2**16])
def test_stacked_triangles_fill_like_one(copies):
    """Winding numbers as large as the triangle count (the fill sums them in 16 bits below 2^14 triangles and
    in 32 bits above) still give the one triangle's pixels."""
    tris = np.repeat(QUAD[:1], copies, axis=0)
    mask, origin = rasterize_silhouette(UV, tris)
    np.testing.assert_array_equal(_canvas(mask, origin, 40, 32), _inside(UV, QUAD[:1], 40, 32))


def test_no_triangles_or_no_pixel_centre_gives_an_empty_mask():
    assert rasterize_silhouette(UV, np.zeros((0, 3), dtype=np.int64))[0].size == 0
    tiny = np.array([[4.1, 4.1], [4.6, 4.2], [4.3, 4.7]])  # between pixel centres
    assert not rasterize_silhouette(tiny, np.array([[0, 1, 2]]))[0].any()
