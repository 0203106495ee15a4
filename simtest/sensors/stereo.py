"""A simulated active-stereo depth camera (RealSense D435-like), rendered from the exact scene geometry.

One view (:meth:`StereoSensor.sense`):

1. Three exact depth renders through the scene's :class:`~simtest.render.rasterizer.Renderer`, each by placing
   the scene's render camera (``data.cam_xpos`` / ``cam_xmat``, as ``SimScene.set_camera`` does) and restoring
   the colour camera afterwards: the projector (depth only, for its shadow), the left IR camera and the right
   IR camera (RGB and depth from one pass when the albedo comes from the surface colour; the materials darkened
   by their reflectance for these two renders, see :class:`~simtest.sensors.ir_render.DiffuseMaterials`). The IR cameras and the
   projector use the IR intrinsics ``K_ir`` (focal ``ir_focal_ratio x width``, principal point of the colour
   camera): the model camera's focal length (``model.cam_intrinsic``) is scaled for these renders and restored.
2. Each IR pixel is back-projected to its world point; the point is lit by the projector when its depth seen
   from the projector matches the projector's own depth map (else it lies in the projector's shadow, the holes
   beside object edges); the lit intensity samples a seeded dot pattern where the point projects into the
   projector, times ``cos(incidence) / r^2``. IR = albedo x (pattern + ambient) + Gaussian sensor noise, 8 bit.
3. ``cv2.StereoSGBM`` matches the rectified pair (both IR cameras share ``K_ir`` and orientation; the right one
   sits ``baseline`` along the left camera's +x), disparity ``d`` (fixed point / 16) -> ``z = f b / d`` in the
   left IR frame, 0 where the matcher fails.
4. The left-IR depth is registered to the colour camera (:func:`register_depth`: each IR pixel's footprint
   splatted into the colour image, nearest surface kept).

Everything random comes from the ``np.random.Generator`` passed in: the same generator state gives the same
bytes. The exact depth, masks and poses are not touched (the sensed depth is a new array).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from functools import lru_cache

import numpy as np

from simtest.camera import CameraModel, intrinsics_matrix, pinhole_pixels, pinhole_points, window_intrinsics
from simtest.errors import ConfigError
from simtest.geometry import Pose
from simtest.rng import child_rng
from simtest.sensors.ir_render import DiffuseMaterials, RenderAt
from simtest.sensors.registration import register_depth

__all__ = ["sensor_rng", "StereoSensor", "StereoView", "STEREO_PRESETS", "stereo_preset", "register_depth", "dot_pattern"]


#: First key of the sensors' seed stream below a run's seed (apart from the scenes' own streams).
_SENSOR_STREAM = 0x5E45


def sensor_rng(seed: int | None, scene_id: int, im_id: int) -> np.random.Generator:
    """The sensor noise generator of view ``im_id`` of scene ``scene_id``: a stream of its own below the run's
    seed, so a sensor draws nothing from the scene's generator (every other file stays the same)."""
    return child_rng(seed, _SENSOR_STREAM, scene_id, im_id)


@dataclass(frozen=True)
class StereoSensor:
    """Parameters of an active-stereo depth camera (lengths in metres, image quantities at the render size).

    Attributes:
        name: Preset name.
        baseline: Distance between the IR cameras (right = left + baseline along the left camera's x).
        ir_focal_ratio: IR focal length / image width (D435 at 640x480: ~0.6-0.67, i.e. 380-430 px).
        left_offset: Left IR camera position in the colour camera frame (OpenCV axes; same orientation).
        projector_offset: Projector position in the left IR frame (between the cameras on the D435).
        projector: Whether the dot projector is on (``False``: passive stereo, ambient light only).
        dot_fraction: Fraction of projector pixels that hold a dot centre.
        dot_sigma: Dot radius (Gaussian sigma), projector pixels.
        pattern_seed: Seed of the dot pattern: the pattern is part of the device, the same in every view (the
            view's generator only draws the sensor noise).
        projector_power: Dot peak intensity on a white surface facing the projector at 1 m.
        ambient: Ambient IR level (flat illumination), times the albedo.
        albedo: ``"rgb"`` (luminance of the rendered colour: dark surfaces return little light) or a constant.
        mirror: Scale each geom's albedo by ``1 - reflectance`` of its material: light a mirror-like surface
            reflects specularly does not come back to the cameras (a MuJoCo mirror, ``reflectance`` 1, is black).
            With ``albedo="rgb"`` the material colours are scaled for the IR renders (before MuJoCo's lighting
            and its clamp to 1); with a constant albedo, per pixel through the IR renders' segmentation.
        noise: Sensor noise std (fraction of full scale 1.0).
        shadow_tolerance: Relative depth tolerance of the projector-visibility test.
        texture_threshold: Pixels whose left-IR local contrast (std over the matching block, fraction of full
            scale) is below it are invalid (the D435's texture threshold): SGBM's smoothness term would
            otherwise fill dark and textureless patches from their neighbours.
        min_depth: Nearest measurable depth; sets numDisparities (f b / min_depth, rounded up to 16).
        max_depth: Depths beyond it are dropped.
        match_margin: The matching window's margin, pixels at 640 px width (scaled with the width): the IR pair
            is simulated and matched only where it can reach the colour image (the colour camera's footprint in
            the left IR image between ``min_depth`` and ``max_depth``, the disparity range left of it, this
            margin around it, see :meth:`match_window`), the rest of the wider IR view is dropped by the
            registration anyway. ``None``: the whole IR image (slower; the results agree on >= 99 % of the colour
            pixels, tested).
        block_size, p1_scale, p2_scale, uniqueness_ratio, speckle_window, speckle_range, disp12_max_diff:
            ``cv2.StereoSGBM_create`` parameters; P1 = p1_scale x block_size^2, P2 = p2_scale x block_size^2;
            the speckle window is in pixels at 640 px width and scales with the image area.
    """

    name: str = "d435-stereo"
    baseline: float = 0.050
    ir_focal_ratio: float = 0.65
    left_offset: tuple[float, float, float] = (0.0, 0.0, 0.0)
    projector_offset: tuple[float, float, float] = (0.025, 0.0, 0.0)
    projector: bool = True
    dot_fraction: float = 0.2
    dot_sigma: float = 0.7
    pattern_seed: int = 435
    projector_power: float = 0.60
    ambient: float = 0.10
    albedo: str | float = "rgb"
    mirror: bool = True
    noise: float = 0.01
    shadow_tolerance: float = 0.01
    texture_threshold: float = 0.02
    min_depth: float = 0.25
    max_depth: float = 6.0
    match_margin: int | None = 16
    block_size: int = 5
    p1_scale: int = 8
    p2_scale: int = 32
    uniqueness_ratio: int = 10
    speckle_window: int = 100
    speckle_range: int = 2
    disp12_max_diff: int = 1

    def __post_init__(self) -> None:
        if not self.baseline > 0 or not self.ir_focal_ratio > 0:
            raise ConfigError(f"stereo baseline and ir_focal_ratio must be > 0, got {self.baseline}, "
                              f"{self.ir_focal_ratio}")
        if self.block_size < 1 or self.block_size % 2 == 0:
            raise ConfigError(f"stereo block_size must be odd and >= 1, got {self.block_size}")
        if not 0 < self.min_depth < self.max_depth:
            raise ConfigError(f"stereo needs 0 < min_depth < max_depth, got {self.min_depth}, {self.max_depth}")
        if self.match_margin is not None and not (isinstance(self.match_margin, int) and self.match_margin >= 0):
            raise ConfigError(f"stereo match_margin must be None or an integer >= 0, got {self.match_margin!r}")
        if not (self.albedo == "rgb" or isinstance(self.albedo, (int, float))):
            raise ConfigError(f"stereo albedo must be 'rgb' or a number, got {self.albedo!r}")

    def replace(self, **changes) -> "StereoSensor":
        return replace(self, **changes)

    # --- geometry --------------------------------------------------------------------------------------
    def ir_K(self, camera: CameraModel) -> np.ndarray:
        """The IR cameras' (and projector's) intrinsics at the colour camera's image size."""
        return _ir_K(self.ir_focal_ratio, camera.K, camera.width)

    def poses(self, camera: CameraModel) -> tuple[Pose, Pose, Pose]:
        """``T_world`` of the left IR camera, the right IR camera and the projector (OpenCV frames)."""
        T = camera.T_world_cam
        R = T.R
        left = Pose(R, T.t + R @ np.asarray(self.left_offset, dtype=np.float64))
        right = Pose(R, left.t + R[:, 0] * self.baseline)
        proj = Pose(R, left.t + R @ np.asarray(self.projector_offset, dtype=np.float64))
        return left, right, proj

    def num_disparities(self, f_ir: float) -> int:
        return int(max(16, 16 * np.ceil(f_ir * self.baseline / self.min_depth / 16.0)))

    def match_window(self, camera: CameraModel) -> tuple[int, int, int, int]:
        """``(r0, r1, c0, c1)``: the rows ``r0:r1`` and columns ``c0:c1`` of the left (and right) IR image that
        are simulated and matched.

        The colour image's corners at ``min_depth`` and ``max_depth``, seen from the left IR camera, bound every
        IR pixel the registration can carry into the colour image; the window is that box plus ``match_margin``
        pixels (the matching block, and context for SGBM's cost aggregation along its paths) and, on the left,
        the disparity range (a left-IR pixel at column u matches the right image at u - d). The whole image when
        ``match_margin`` is None. It depends on the intrinsics and the rig only (the IR cameras move with the
        colour camera), so it is computed once per image size.
        """
        return _windows(self, _key(camera.K), camera.width, camera.height)[0]

    def projector_window(self, camera: CameraModel) -> tuple[int, int, int, int]:
        """The projector pixels (same layout) that can light a point of the matching window between
        ``min_depth`` and ``max_depth``: the projector's depth is rendered there only."""
        return _windows(self, _key(camera.K), camera.width, camera.height)[1]

    def matcher(self, camera: CameraModel):
        """The ``cv2.StereoSGBM`` matcher of the IR pair at ``camera``'s image size (3-way mode)."""
        import cv2

        bs = self.block_size
        area = camera.width * camera.height / (640.0 * 480.0)
        return cv2.StereoSGBM_create(minDisparity=0, numDisparities=self.num_disparities(self.ir_K(camera)[0, 0]),
                                     blockSize=bs, P1=self.p1_scale * bs * bs, P2=self.p2_scale * bs * bs,
                                     disp12MaxDiff=self.disp12_max_diff, uniquenessRatio=self.uniqueness_ratio,
                                     speckleWindowSize=max(4, int(round(self.speckle_window * area))),
                                     speckleRange=self.speckle_range, mode=cv2.STEREO_SGBM_MODE_SGBM_3WAY)

    # --- one view --------------------------------------------------------------------------------------
    def sense(self, renderer, data, camera_id: int, camera: CameraModel, rng: np.random.Generator) -> np.ndarray:
        """Sensed depth (H, W) float32 metres in the colour ``camera`` (0 = no measurement); see the module."""
        return self.sense_view(renderer, data, camera_id, camera, rng).depth

    def sense_view(self, renderer, data, camera_id: int, camera: CameraModel,
                   rng: np.random.Generator) -> "StereoView":
        """:meth:`sense` with the intermediate images (IR pair, left-IR depth, exact left-IR depth)."""

        K_ir = self.ir_K(camera)
        T_left, T_right, T_proj = self.poses(camera)
        use_rgb = self.albedo == "rgb"
        # The mirror term: with the rendered colour, in the materials themselves (one RGB + depth pass per IR
        # camera); with a constant albedo, per pixel through the segmentation.
        diffuse = _diffuse_fraction(renderer.model) if self.mirror and not use_rgb else None
        pattern = dot_pattern(camera.width, camera.height, self.dot_fraction, self.dot_sigma, self.pattern_seed) \
            if self.projector else None
        r0, r1, c0, c1 = window = self.match_window(camera)
        proj_win = self.projector_window(camera)
        proj_depth, left_w, right_w = self.render_ir(renderer, data, camera_id, camera)
        # left, then right; drawn for the whole image, so a pixel's noise does not depend on the window
        noise = [_gaussian(rng, (camera.height, camera.width))[r0:r1, c0:c1] for _ in range(2)]
        if pattern is not None:
            pr0, pr1, pc0, pc1 = proj_win
            pattern = pattern[pr0:pr1, pc0:pc1]
        K_win, K_proj = window_intrinsics(K_ir, window), window_intrinsics(K_ir, proj_win)
        ir_left, flat = self._left_image(left_w, T_left, K_win, K_proj, T_proj, proj_depth, pattern, noise[0],
                                         diffuse)
        ir = [ir_left, self._ir_image(right_w, T_right, K_win, K_proj, T_proj, proj_depth, pattern, noise[1],
                                      diffuse)]
        f = float(K_ir[0, 0])
        disp = self.matcher(camera).compute(ir[0], ir[1])  # fixed point, 16 x disparity
        depth_win = np.zeros(disp.shape, dtype=np.float32)
        np.divide(np.float32(16.0 * f * self.baseline), disp, out=depth_win, where=disp > 0, dtype=np.float32)
        if flat is not None:
            depth_win[flat] = 0.0
        depth_win[(depth_win < self.min_depth) | (depth_win > self.max_depth)] = 0.0
        full = (camera.height, camera.width)
        depth_ir = _uncrop(depth_win, full, window)
        ir = [_uncrop(a, full, window) for a in ir]
        T_col_ir = camera.T_cam_world @ T_left
        depth = register_depth(depth_ir, K_ir, T_col_ir, camera.K, camera.width, camera.height)
        return StereoView(depth, ir[0], ir[1], depth_ir, _uncrop(left_w.depth, full, window), K_ir, window)

    def render_ir(self, renderer, data, camera_id: int, camera: CameraModel):
        """The sensor's GL passes through the scene's ``renderer``: ``(projector depth, left frame, right
        frame)``, the projector's depth-only pass over :meth:`projector_window` (None without the projector)
        and the IR cameras' RGB + depth passes over :meth:`match_window` (segmentation too with a constant
        albedo and ``mirror``); the render camera and the materials are restored afterwards."""
        use_rgb = self.albedo == "rgb"
        seg = self.mirror and not use_rgb
        T_left, T_right, T_proj = self.poses(camera)
        window = self.match_window(camera)
        with RenderAt(renderer, data, camera_id, camera, self.ir_K(camera)) as at:
            proj = at.render(T_proj, rgb=False, window=self.projector_window(camera)).depth if self.projector \
                else None
            with DiffuseMaterials(renderer.model, self.mirror and use_rgb):
                left = at.render(T_left, rgb=use_rgb, seg=seg, window=window)
                right = at.render(T_right, rgb=use_rgb, seg=seg, window=window)
        return proj, left, right

    def _left_image(self, frame, T_world_ir: Pose, K_win: np.ndarray, K_proj: np.ndarray, T_proj: Pose, proj_depth,
                    pattern, noise: np.ndarray, diffuse: np.ndarray | None) -> tuple[np.ndarray, np.ndarray | None]:
        """The left IR image and its texture-threshold mask: True where the local contrast (std over the
        matching block, fraction of full scale) is below ``texture_threshold`` (None when the threshold is 0)."""
        import cv2

        ir = self._ir_image(frame, T_world_ir, K_win, K_proj, T_proj, proj_depth, pattern, noise, diffuse)
        if self.texture_threshold <= 0:
            return ir, None
        bs = (self.block_size, self.block_size)
        img = ir.astype(np.float32)
        img *= np.float32(1.0 / 255.0)
        mean = cv2.boxFilter(img, -1, bs)
        var = cv2.boxFilter(img * img, -1, bs)
        var -= mean * mean
        return ir, var < np.float32(self.texture_threshold) ** 2

    def _ir_image(self, frame, T_world_ir: Pose, K_win: np.ndarray, K_proj: np.ndarray, T_proj: Pose, proj_depth,
                  pattern, noise: np.ndarray, diffuse: np.ndarray | None = None) -> np.ndarray:
        """The 8-bit IR image of one camera from its exact depth (and colour) in the matching window, float32
        throughout; ``noise`` is the camera's standard normal sensor-noise draw (the window's shape). ``K_win``:
        the IR intrinsics of the matching window, ``K_proj`` those of the projector's window (``K_ir`` with the
        principal point shifted by each window's corner), which ``proj_depth`` and ``pattern`` cover.

        The pixel rays come from :func:`_unit_rays` (``camera.pinhole_points`` at unit depth, broadcast
        (1, W) and (H, 1)); the projector shares the camera's orientation and ``K_ir``, so a point's projector
        pixel is ``pinhole_pixels`` of its projector-frame coordinates, written out in float32 here. The surface
        normal is the cross product of the back-projected surface's pixel derivatives, in closed form from the
        depth gradients ``z_u``, ``z_v``: ``n ~ (-fx z_u, -fy z_v, fx x_n z_u + fy y_n z_v + z)`` with
        ``(x_n, y_n, 1)`` the pixel's ray.
        """
        import cv2

        z = frame.depth
        h, w = z.shape
        hit = z > 0
        if self.albedo == "rgb":
            # luminance 0.299 R + 0.587 G + 0.114 B, 0-1
            albedo = cv2.cvtColor(frame.rgb, cv2.COLOR_RGB2GRAY).astype(np.float32)
            albedo *= np.float32(1.0 / 255.0)
        else:
            albedo = np.full((h, w), float(self.albedo), dtype=np.float32)
        if diffuse is not None:
            albedo *= diffuse[frame.seg]  # seg -1 (background) indexes the last entry, 1
        albedo[~hit] = 0.0
        ir = albedo * np.float32(self.ambient)
        if pattern is not None:
            f32 = np.float32
            fx, fy, cx, cy = (f32(K_proj[0, 0]), f32(K_proj[1, 1]), f32(K_proj[0, 2]), f32(K_proj[1, 2]))
            xn, yn = _unit_rays(K_win, w, h)
            # The projector's frame is the IR frame shifted by o (same orientation by construction of poses()).
            o = (T_world_ir.R.T @ (T_proj.t - T_world_ir.t)).astype(np.float32)
            xp = xn * z
            xp -= o[0]
            yp = yn * z
            yp -= o[1]
            zp = z - o[2]
            front = zp > 1e-4
            front &= hit
            inv = np.divide(f32(1.0), zp, out=np.ones_like(zp), where=front)
            up = xp * inv
            up *= fx
            up += cx
            vp = np.multiply(yp, inv, out=inv)
            vp *= fy
            vp += cy
            # Lit: the projector sees this point (its own depth there matches), else it is in the projector's shadow.
            seen = cv2.remap(proj_depth, up, vp, cv2.INTER_NEAREST, borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
            seen -= zp
            tol = zp * f32(self.shadow_tolerance)
            tol += f32(1e-3)
            lit = np.abs(seen, out=seen) <= tol
            lit &= front
            # cos(incidence) between the surface normal n and the projector ray p, and the fall-off 1 / |p|^2:
            # with a = fx z_u, b = fy z_v, n = (-a, -b, x_n a + y_n b + z) and, since p = (x_n z, y_n z, z) - o,
            # n . p = a (o_x - x_n o_z) + b (o_y - y_n o_z) + z p_z.
            a = cv2.Sobel(z, cv2.CV_32F, 1, 0, ksize=1, scale=0.5 * float(fx), borderType=cv2.BORDER_REPLICATE)
            b = cv2.Sobel(z, cv2.CV_32F, 0, 1, ksize=1, scale=0.5 * float(fy), borderType=cv2.BORDER_REPLICATE)
            tmp = np.multiply(yn, b, out=tol)
            nz = xn * a
            nz += tmp
            nz += z
            dot = a * (o[0] - xn * o[2])
            if o[1] or o[2]:
                dot += np.multiply(b, o[1] - yn * o[2], out=tmp)
            dot += np.multiply(z, zp, out=tmp)
            np.abs(dot, out=dot)
            n2 = np.multiply(a, a, out=a)
            n2 += np.multiply(b, b, out=b)
            n2 += np.multiply(nz, nz, out=nz)
            r2 = np.multiply(xp, xp, out=xp)
            r2 += np.multiply(yp, yp, out=yp)
            r2 += np.multiply(zp, zp, out=tmp)
            r2 += f32(1e-12)
            n2 *= r2
            norm = np.sqrt(n2, out=n2)  # |n| |p|
            norm += f32(1e-12)
            norm *= r2
            gain = cv2.remap(pattern, up, vp, cv2.INTER_LINEAR, borderMode=cv2.BORDER_CONSTANT, borderValue=0.0)
            gain *= dot
            gain /= norm
            gain *= lit
            gain *= f32(self.projector_power)
            gain *= albedo
            ir += gain
        ir += np.float32(self.noise) * noise
        ir *= np.float32(255.0)
        return np.clip(np.rint(ir, out=ir), 0, 255, out=ir).astype(np.uint8)


@dataclass(frozen=True)
class StereoView:
    """One sensed view: ``depth`` in the colour camera (metres, 0 = none), the 8-bit IR pair, the matched depth
    in the left IR frame, the exact left-IR depth, the IR intrinsics, and the matching window ``(r0, r1, c0,
    c1)`` (:meth:`StereoSensor.match_window`): the IR pair, the matched and the exact left-IR depth are 0 outside
    it."""

    depth: np.ndarray
    ir_left: np.ndarray
    ir_right: np.ndarray
    depth_ir: np.ndarray
    exact_ir: np.ndarray
    K_ir: np.ndarray
    window: tuple[int, int, int, int]


def _ir_K(focal_ratio: float, K: np.ndarray, width: int) -> np.ndarray:
    """IR intrinsics: focal ``focal_ratio x width``, the colour camera's principal point."""
    f = focal_ratio * width
    return intrinsics_matrix(f, f, K[0, 2], K[1, 2])


def _key(K: np.ndarray) -> tuple[float, ...]:
    return tuple(float(k) for k in np.asarray(K, dtype=np.float64).ravel())


def _box(u: np.ndarray, v: np.ndarray, margin: int, width: int, height: int,
         left: int = 0) -> tuple[int, int, int, int]:
    """The pixel box ``(r0, r1, c0, c1)`` around points ``(u, v)`` (the pixels a nearest lookup can reach, plus
    ``margin``, plus ``left`` more columns on the left), clipped to the image."""
    c0 = int(np.clip(np.floor(u.min() + 0.5) - margin - left, 0, width))
    c1 = int(np.clip(np.floor(u.max() + 0.5) + 1 + margin, 0, width))
    r0 = int(np.clip(np.floor(v.min() + 0.5) - margin, 0, height))
    r1 = int(np.clip(np.floor(v.max() + 0.5) + 1 + margin, 0, height))
    return r0, r1, c0, c1


def _corners(window: tuple[int, int, int, int]) -> tuple[np.ndarray, np.ndarray]:
    """The outer pixel corners of a window, twice (for two depths)."""
    r0, r1, c0, c1 = window
    u = np.array([c0 - 0.5, c1 - 0.5, c0 - 0.5, c1 - 0.5] * 2)
    v = np.array([r0 - 0.5, r0 - 0.5, r1 - 0.5, r1 - 0.5] * 2)
    return u, v


@lru_cache(maxsize=32)
def _windows(sensor: StereoSensor, K: tuple[float, ...], width: int,
             height: int) -> tuple[tuple[int, int, int, int], tuple[int, int, int, int]]:
    """:meth:`StereoSensor.match_window` and :meth:`StereoSensor.projector_window` for colour intrinsics ``K``."""
    whole = (0, height, 0, width)
    if sensor.match_margin is None:
        return whole, whole
    Kc = np.asarray(K).reshape(3, 3)
    K_ir = _ir_K(sensor.ir_focal_ratio, Kc, width)
    z = np.repeat([sensor.min_depth, sensor.max_depth], 4)
    # the left IR camera is the colour camera moved by left_offset, same orientation
    u, v = _corners(whole)
    p = pinhole_points(Kc, u, v, z) - np.asarray(sensor.left_offset, dtype=np.float64)
    ui, vi = pinhole_pixels(K_ir, p)
    m = int(np.ceil(sensor.match_margin * width / 640.0)) + 1  # + the registration's nearest-pixel rounding
    ndisp = sensor.num_disparities(float(K_ir[0, 0]))
    window = _box(ui, vi, m, width, height, left=ndisp)
    if window[3] - window[2] <= ndisp or window[1] <= window[0]:  # nothing of the colour image is matchable
        return whole, whole
    # the projector is the left IR camera moved by projector_offset, same orientation and intrinsics; it has to
    # cover the points of both IR cameras' windows (the right camera: the left one moved by the baseline along x)
    o = np.asarray(sensor.projector_offset, dtype=np.float64)
    u, v = _corners(window)
    rays = pinhole_points(K_ir, u, v, z)
    p = np.concatenate([rays - o, rays + np.array([sensor.baseline, 0.0, 0.0]) - o])
    if np.any(p[:, 2] <= 1e-6):
        return window, whole
    up, vp = pinhole_pixels(K_ir, p)
    return window, _box(up, vp, 1, width, height)


def _uncrop(a: np.ndarray, shape: tuple[int, int], window: tuple[int, int, int, int]) -> np.ndarray:
    """``a`` (the window) placed in a zero image of ``shape``."""
    r0, r1, c0, c1 = window
    if a.shape == tuple(shape):
        return a
    out = np.zeros(shape, dtype=a.dtype)
    out[r0:r1, c0:c1] = a
    return out


def _gaussian(rng: np.random.Generator, shape: tuple[int, int]) -> np.ndarray:
    """Standard normal sensor noise (float32) by inverse-CDF sampling: 16 random bits per pixel from ``rng`` index
    a table of the normal quantiles at ``(k + 0.5) / 65536`` (tails cut at 4.3 sigma, std 1 - 1e-5); 4x faster
    than ``rng.standard_normal``; below the 8-bit quantisation of the IR image the two cannot be told apart."""
    bits = np.frombuffer(rng.bytes(2 * shape[0] * shape[1]), dtype="<u2").reshape(shape)
    return np.take(_normal_quantiles(), bits)


@lru_cache(maxsize=1)
def _normal_quantiles() -> np.ndarray:
    from scipy.special import ndtri

    out = ndtri((np.arange(65536, dtype=np.float64) + 0.5) / 65536.0).astype(np.float32)
    out.setflags(write=False)
    return out


def _unit_rays(K: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """The pixel rays at unit depth under ``K``: ``x/z`` of each column (1, W) and ``y/z`` of each row (H, 1),
    float32 (``camera.pinhole_points`` at z = 1), cached per intrinsics and size."""
    return _rays(tuple(float(k) for k in np.asarray(K, dtype=np.float64).ravel()), int(width), int(height))


@lru_cache(maxsize=8)
def _rays(K: tuple[float, ...], width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    Km = np.asarray(K).reshape(3, 3)
    u, v = np.arange(width, dtype=np.float64), np.arange(height, dtype=np.float64)
    xn = pinhole_points(Km, u, np.full(width, Km[1, 2]), np.ones(width))[:, 0]
    yn = pinhole_points(Km, np.full(height, Km[0, 2]), v, np.ones(height))[:, 1]
    out = xn.astype(np.float32)[None, :], yn.astype(np.float32)[:, None]
    for a in out:
        a.setflags(write=False)
    return out


def _diffuse_fraction(model) -> np.ndarray:
    """(ngeom + 1,) float32: ``1 - reflectance`` of each geom's material (1 without one), and 1 for the
    background (the last entry, for seg = -1)."""
    matid = np.asarray(model.geom_matid)
    refl = np.zeros(matid.shape, dtype=np.float32)
    has = matid >= 0
    refl[has] = np.asarray(model.mat_reflectance, dtype=np.float32)[matid[has]]
    return np.append(np.clip(1.0 - refl, 0.0, 1.0), np.float32(1.0)).astype(np.float32)


def dot_pattern(width: int, height: int, fraction: float, sigma: float, seed: int) -> np.ndarray:
    """The projector's pseudo-random dot pattern (H, W) in [0, 1], fixed by ``seed`` (a property of the device,
    like the D435's diffractive element): ``fraction x W x H`` Gaussian dots of std ``sigma`` pixels at
    sub-pixel positions, peak 1 (overlaps add, clipped at 1). Cached per arguments; read-only."""
    return _dot_pattern(int(width), int(height), float(fraction), float(sigma), int(seed))


@lru_cache(maxsize=8)
def _dot_pattern(width: int, height: int, fraction: float, sigma: float, seed: int) -> np.ndarray:
    import cv2

    rng = np.random.default_rng(seed)
    n = int(round(fraction * width * height))
    xs = rng.uniform(-0.5, width - 0.5, n)
    ys = rng.uniform(-0.5, height - 0.5, n)
    x0, y0 = np.floor(xs).astype(np.int64), np.floor(ys).astype(np.int64)
    a, b = xs - x0, ys - y0
    grid = np.zeros((height + 2, width + 2), dtype=np.float64)  # one pixel of margin on each side
    for dx, dy, wgt in ((0, 0, (1 - a) * (1 - b)), (1, 0, a * (1 - b)), (0, 1, (1 - a) * b), (1, 1, a * b)):
        np.add.at(grid, (y0 + dy + 1, x0 + dx + 1), wgt)
    blurred = cv2.GaussianBlur(grid, (0, 0), sigmaX=sigma, sigmaY=sigma, borderType=cv2.BORDER_CONSTANT)
    out = np.clip(blurred[1:-1, 1:-1] * (2 * np.pi * sigma ** 2), 0.0, 1.0).astype(np.float32)
    out.setflags(write=False)
    return out


#: The presets: an active D435-like sensor and the same rig without its projector.
STEREO_PRESETS: dict[str, StereoSensor] = {
    "d435-stereo": StereoSensor(),
    "passive-stereo": StereoSensor(name="passive-stereo", projector=False, ambient=0.6),
}


def stereo_preset(name: str) -> StereoSensor:
    """The preset ``name`` (:data:`STEREO_PRESETS`).

    Raises:
        ConfigError: Unknown name (the message lists the presets).
    """
    try:
        return STEREO_PRESETS[name]
    except KeyError:
        raise ConfigError(f"unknown stereo preset {name!r}; known: {sorted(STEREO_PRESETS)}") from None
