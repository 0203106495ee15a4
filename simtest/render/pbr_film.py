"""The path tracer's film for any pinhole K: Mitsuba's perspective sensor has square pixels, K need not.

Mitsuba's ``perspective`` sensor has one focal length and refuses a scale in its ``to_world`` ("Scale factors in
the camera-to-world transformation are not allowed"). :func:`film_grid` gives the film :mod:`simtest.render.pbr`
renders instead for a K with ``fx != fy``: the larger focal length on both axes, ``ratio = max / min`` times
more pixels than the image along the other axis over the same field of view, its principal point placed so that
image pixel ``j`` is exactly the film's ``[ratio j, ratio (j + 1)]`` (the rays K gives it);
:func:`resample_to_image` averages the film back onto the image's pixels. Square pixels keep the image's grid.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from simtest.camera import CameraModel

__all__ = ["FilmGrid", "film_grid", "resample_to_image", "SQUARE_TOL"]


@dataclass(frozen=True)
class FilmGrid:
    """The square-pixel film the path tracer renders for a pinhole camera, and how it maps onto the image.

    Mitsuba's perspective sensor has one focal length (square pixels) and refuses a scale in its ``to_world``.
    The film takes the larger of ``fx``, ``fy`` as ``focal`` on both axes: along the axis with that focal length
    it is the image's own pixel grid; along the other (``axis``) it samples the same field of view ``ratio =
    focal / f_axis >= 1`` times more densely, and :func:`resample_to_image` averages it back onto the image's
    pixels. With the film's principal point at ``ratio (c + 0.5) - 0.5`` along ``axis``, image pixel ``j``
    covers exactly the film's ``[ratio j, ratio (j + 1)]`` (film pixel ``i`` covering ``[i, i + 1]``), i.e. the
    rays K gives it: no pixel moves, only the film's pixels are narrower than the image's along ``axis``.

    Attributes:
        width, height: Film size (pixels); the image's size when the pixels are square.
        focal: The film's focal length on both axes (pixels), ``max(fx, fy)``.
        cx, cy: The film's principal point (pixels, OpenCV: pixel centres at integers).
        axis: The resampled image axis: 1 (columns, ``fy > fx``), 0 (rows, ``fx > fy``) or None (``fx == fy``:
            the film is the image).
        ratio: Film pixels per image pixel along ``axis`` (1.0 when None).
    """

    width: int
    height: int
    focal: float
    cx: float
    cy: float
    axis: int | None
    ratio: float


#: Focal lengths closer than this relative difference count as equal (square pixels, no resampling).
SQUARE_TOL = 1e-9


def film_grid(camera: CameraModel) -> FilmGrid:
    """The :class:`FilmGrid` of ``camera``'s intrinsics and image size."""
    K, w, h = camera.K, camera.width, camera.height
    fx, fy, cx, cy = (float(v) for v in (K[0, 0], K[1, 1], K[0, 2], K[1, 2]))
    if abs(fx - fy) <= SQUARE_TOL * max(fx, fy):
        return FilmGrid(w, h, fx, cx, cy, None, 1.0)
    if fy > fx:
        r = fy / fx
        return FilmGrid(_film_size(w, r), h, fy, r * (cx + 0.5) - 0.5, cy, 1, r)
    r = fx / fy
    return FilmGrid(w, _film_size(h, r), fx, cx, r * (cy + 0.5) - 0.5, 0, r)


def _film_size(n: int, ratio: float) -> int:
    """Film pixels that cover ``n`` image pixels at ``ratio`` film pixels each (a rounding error is no pixel)."""
    return int(np.ceil(n * ratio - 1e-6))


def _area_taps(n: int, ratio: float, n_film: int) -> tuple[np.ndarray, np.ndarray]:
    """``(index, weight)``, both (n, taps): image pixel ``j`` is ``sum_k weight[j, k] * film[index[j, k]]``, the
    film's mean over ``[ratio j, ratio (j + 1)]`` (each film pixel weighted by the length of it inside)."""
    lo = ratio * np.arange(n, dtype=np.float64)
    idx = np.floor(lo).astype(np.int64)[:, None] + np.arange(int(np.ceil(ratio)) + 1)[None, :]
    overlap = np.minimum(lo[:, None] + ratio, idx + 1.0) - np.maximum(lo[:, None], idx)
    weight = np.clip(overlap, 0.0, None)
    weight /= weight.sum(axis=1, keepdims=True)
    return np.minimum(idx, n_film - 1), weight  # taps past the film's end have weight 0


def resample_to_image(film: np.ndarray, grid: FilmGrid, width: int, height: int) -> np.ndarray:
    """A rendered film (H', W', C) of ``grid`` as the ``height`` x ``width`` image: each image pixel the
    area-weighted mean of the film pixels its footprint covers along ``grid.axis`` (linear values: radiance);
    the film itself when the pixels are square."""
    if grid.axis is None:
        return film
    n = width if grid.axis == 1 else height
    idx, weight = _area_taps(n, grid.ratio, film.shape[grid.axis])
    shape = [1] * film.ndim
    shape[grid.axis] = n
    out = np.zeros(film.shape[:grid.axis] + (n,) + film.shape[grid.axis + 1:], dtype=np.float32)
    for k in range(idx.shape[1]):
        out += np.take(film, idx[:, k], axis=grid.axis) * weight[:, k].astype(np.float32).reshape(shape)
    return out
