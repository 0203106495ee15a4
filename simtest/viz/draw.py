"""Drawing primitives for pose pictures: projection of model points, 3D boxes, axes, mask contours, labels.

Frames and units: poses are ``T_cam_obj`` (``R`` 3x3 model -> camera, ``t`` (3,) metres) in the OpenCV camera
frame (x right, y down, z forward); model points are metres in the model frame. Pixel coordinates follow
OpenCV (:mod:`simtest.camera`): the centre of pixel ``(row v, col u)`` is the image point ``(u, v)``.

Every drawing function takes ``scale``: the factor by which the canvas was enlarged from the camera's image
(an integer upscale for small images). A camera pixel point ``x`` lands at ``scale * (x + 0.5) - 0.5`` on the
canvas, so pixel edges stay on pixel edges. Images are RGB uint8 (H, W, 3) and are drawn on in place.
"""

from __future__ import annotations

import cv2
import numpy as np

from simtest.camera import pinhole_pixels
from simtest.render.zbuffer import render_depth

__all__ = ["GT_COLOUR", "EST_COLOUR", "AXIS_COLOURS", "BAD_COLOUR", "palette", "project_model_points",
           "box_corner_pixels", "BOX_EDGES", "to_canvas", "draw_box", "draw_axes", "mask_contours",
           "draw_mask_contour", "draw_label", "mesh_silhouette", "canvas_intrinsics", "draw_polyline_points"]

#: Colour of ground truth on evaluation pages (RGB): green.
GT_COLOUR = (40, 220, 60)
#: Colour of an estimate (RGB): magenta, far from the green of ground truth and from the scenes' greys.
EST_COLOUR = (255, 40, 220)
#: Colour of a failed target or a message (RGB): red.
BAD_COLOUR = (235, 40, 40)
#: Axis colours x, y, z (RGB): red, green, blue.
AXIS_COLOURS = ((230, 30, 30), (30, 200, 30), (40, 90, 255))
#: The 12 edges of the box whose corner ``i`` takes the max along axis ``b`` when bit ``b`` of ``i`` is set
#: (the corner order of :attr:`simtest.objects.ObjectModel.keypoints_bbox`).
BOX_EDGES: tuple[tuple[int, int], ...] = tuple((i, i | (1 << b)) for b in range(3) for i in range(8)
                                               if not i & (1 << b))
#: Fixed-point bits of OpenCV's sub-pixel drawing.
_SHIFT = 4
_ONE = 1 << _SHIFT
_TAB10 = ((31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189), (140, 86, 75),
          (227, 119, 194), (188, 189, 34), (23, 190, 207), (127, 127, 127))


def palette(i: int) -> tuple[int, int, int]:
    """A distinct RGB colour for instance ``i`` (matplotlib's tab10, brightened for dark scenes)."""
    r, g, b = _TAB10[int(i) % len(_TAB10)]
    return (min(255, r + 40), min(255, g + 40), min(255, b + 40))


def project_model_points(K: np.ndarray, R: np.ndarray, t: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Pixels (N, 2) ``(u, v)`` of model points (N, 3), metres, at pose ``(R, t)``: ``K (R x + t)``
    (OpenCV pixel centres); NaN for points at or behind the camera (z <= 1 mm)."""
    p = np.asarray(points, dtype=np.float64) @ np.asarray(R, dtype=np.float64).T + np.asarray(t, dtype=np.float64)
    z = p[:, 2]
    with np.errstate(divide="ignore", invalid="ignore"):
        u, v = pinhole_pixels(np.asarray(K, dtype=np.float64), p)
    uv = np.stack([u, v], axis=1)
    uv[z <= 1e-3] = np.nan
    return uv


def box_corner_pixels(K: np.ndarray, R: np.ndarray, t: np.ndarray, corners: np.ndarray) -> np.ndarray:
    """Pixels (8, 2) of the model's 3D bounding-box corners (8, 3), metres (``ObjectModel.keypoints_bbox``),
    at pose ``(R, t)``: ``K (R x + t)``."""
    return project_model_points(K, R, t, corners)


def to_canvas(uv: np.ndarray, scale: float) -> np.ndarray:
    """Camera pixel points (N, 2) -> canvas points (N, 2) of an image enlarged ``scale`` times."""
    return float(scale) * (np.asarray(uv, dtype=np.float64) + 0.5) - 0.5


def _fixed(p: np.ndarray) -> tuple[int, int]:
    return int(round(p[0] * _ONE)), int(round(p[1] * _ONE))


def _segment(img: np.ndarray, a: np.ndarray, b: np.ndarray, colour, thickness: int) -> None:
    if not (np.all(np.isfinite(a)) and np.all(np.isfinite(b))):
        return
    lim = 4.0 * max(img.shape)  # keep far points inside OpenCV's fixed-point range
    a, b = np.clip(a, -lim, lim), np.clip(b, -lim, lim)
    cv2.line(img, _fixed(a), _fixed(b), colour, thickness, cv2.LINE_AA, _SHIFT)


def draw_box(img: np.ndarray, corners_uv: np.ndarray, colour, scale: float = 1.0, thickness: int = 1) -> None:
    """The 12 edges of a projected 3D box (corner pixels (8, 2) from :func:`box_corner_pixels`, antialiased)
    and a solid dot (not antialiased: the corner pixel has exactly ``colour``) on each corner."""
    pts = to_canvas(corners_uv, scale)
    for i, j in BOX_EDGES:
        _segment(img, pts[i], pts[j], colour, thickness)
    for p in pts:
        if np.all(np.isfinite(p)) and np.all(np.abs(p) < 4 * max(img.shape)):
            cv2.circle(img, _fixed(p), (max(1, thickness) + 1) * _ONE // 2 + _ONE // 2, colour, -1, cv2.LINE_8, _SHIFT)


def draw_axes(img: np.ndarray, K: np.ndarray, R: np.ndarray, t: np.ndarray, length: float, scale: float = 1.0,
              thickness: int = 2, colours=AXIS_COLOURS) -> None:
    """The model axes x, y, z (``length`` metres each, from the model origin) at pose ``(R, t)``, coloured
    ``colours`` (default red, green, blue)."""
    pts = np.vstack([np.zeros(3), np.eye(3) * float(length)])
    uv = to_canvas(project_model_points(K, R, t, pts), scale)
    for k in range(3):
        _segment(img, uv[0], uv[k + 1], colours[k], thickness)


def mask_contours(mask: np.ndarray) -> list[np.ndarray]:
    """Outer and inner boundaries of a boolean mask (H, W) as lists of pixel points (N, 2) ``(u, v)``: each
    point is a mask pixel with a 4-neighbour outside the mask (OpenCV ``findContours``, every point kept)."""
    m = np.ascontiguousarray(mask, dtype=np.uint8)
    if not m.any():
        return []
    contours, _ = cv2.findContours(m, cv2.RETR_LIST, cv2.CHAIN_APPROX_NONE)
    return [c.reshape(-1, 2) for c in contours]


def draw_polyline_points(img: np.ndarray, points: np.ndarray, colour, thickness: int = 1, dash: int = 0) -> None:
    """Paint canvas pixels ``points`` (N, 2) integer ``(u, v)`` in order; ``dash > 0``: only runs of ``dash``
    points, every other run left out (a dashed line); ``thickness`` > 1 grows each painted pixel to a square."""
    pts = np.asarray(points, dtype=np.int64).reshape(-1, 2)
    if dash > 0:
        pts = pts[(np.arange(len(pts)) // int(dash)) % 2 == 0]
    h, w = img.shape[:2]
    r0 = -(int(thickness) - 1) // 2
    for dy in range(r0, r0 + int(thickness)):
        for dx in range(r0, r0 + int(thickness)):
            u, v = pts[:, 0] + dx, pts[:, 1] + dy
            ok = (u >= 0) & (u < w) & (v >= 0) & (v < h)
            img[v[ok], u[ok]] = colour


def draw_mask_contour(img: np.ndarray, mask: np.ndarray, colour, scale: int = 1, thickness: int = 1,
                      dash: int = 0) -> None:
    """Draw the boundary of ``mask`` (H, W) bool, camera pixels, on a canvas ``scale`` times larger: the mask
    is enlarged by nearest neighbour and its boundary pixels painted (they lie on the mask's edge, inside
    it). ``dash`` > 0 gives a dashed line (runs of ``dash`` canvas pixels)."""
    s = int(scale)
    m = mask if s == 1 else cv2.resize(np.ascontiguousarray(mask, dtype=np.uint8), None, fx=s, fy=s,
                                       interpolation=cv2.INTER_NEAREST)
    for c in mask_contours(m):
        draw_polyline_points(img, c, colour, thickness, dash)


def _overlaps(a: tuple[int, int, int, int], b: tuple[int, int, int, int]) -> bool:
    return a[0] < b[0] + b[2] and b[0] < a[0] + a[2] and a[1] < b[1] + b[3] and b[1] < a[1] + a[3]


def draw_label(img: np.ndarray, text: str, org: tuple[float, float], colour=(255, 255, 255), font_scale: float = 0.5,
               bg=(0, 0, 0), alpha: float = 0.6, avoid: list | None = None) -> tuple[int, int, int, int]:
    """``text`` on a translucent box whose top-left corner is at canvas point ``org`` (kept inside the image);
    returns the box ``(x, y, w, h)``. ``font_scale`` 0.5 (Hershey simplex) is about 12 px high. ``avoid``: boxes
    of labels already drawn; the box moves down (a few steps) off them, and is appended to the list."""
    font, th = cv2.FONT_HERSHEY_SIMPLEX, 1
    (tw, tht), base = cv2.getTextSize(text, font, font_scale, th)
    pad = 3
    w, h = tw + 2 * pad, tht + base + 2 * pad
    H, W = img.shape[:2]
    x = int(np.clip(org[0], 0, max(0, W - w)))
    y = int(np.clip(org[1], 0, max(0, H - h)))
    for _ in range(8):
        if avoid is None or not any(_overlaps((x, y, w, h), b) for b in avoid):
            break
        y = int(np.clip(y + h, 0, max(0, H - h)))
    if avoid is not None:
        avoid.append((x, y, w, h))
    roi = img[y:y + h, x:x + w]
    roi[:] = (roi * (1.0 - alpha) + np.asarray(bg, dtype=np.float64) * alpha).astype(np.uint8)
    cv2.putText(img, text, (x + pad, y + pad + tht), font, font_scale, colour, th, cv2.LINE_AA)
    return x, y, w, h


def canvas_intrinsics(K: np.ndarray, scale: float) -> np.ndarray:
    """Intrinsics of a canvas ``scale`` times larger than the camera image (pixel centres kept at integers:
    ``f' = s f``, ``c' = s (c + 0.5) - 0.5``)."""
    K = np.asarray(K, dtype=np.float64)
    s = float(scale)
    return np.array([[s * K[0, 0], s * K[0, 1], s * (K[0, 2] + 0.5) - 0.5],
                     [0.0, s * K[1, 1], s * (K[1, 2] + 0.5) - 0.5], [0.0, 0.0, 1.0]])


def mesh_silhouette(K: np.ndarray, R: np.ndarray, t: np.ndarray, vertices: np.ndarray, faces: np.ndarray,
                    width: int, height: int, scale: int = 1) -> np.ndarray:
    """The projected mesh's silhouette (height * scale, width * scale) bool at pose ``(R, t)``: the pixels
    whose centre a triangle covers (:func:`simtest.render.zbuffer.render_depth`, the rule of simtest's masks,
    so at the ground-truth pose it equals the amodal mask). Vertices metres, model frame; triangles with a
    vertex behind the near plane are left out."""
    s = int(scale)
    depth = render_depth(vertices, faces, R, t, canvas_intrinsics(K, s), int(width) * s, int(height) * s)
    return depth > 0
