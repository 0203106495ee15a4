"""Environment lighting for the path tracer: procedural skies and studios, and HDR files.

Equirectangular convention (world frame, z up): an (H, 2H, 3) float32 array of LINEAR radiance; row r spans
the polar angle theta in [pi r / H, pi (r + 1) / H] measured from +z (row 0 = zenith, last row = nadir);
column c spans the azimuth phi in [2 pi c / W, 2 pi (c + 1) / W] measured from +x toward +y; the direction of
(theta, phi) is (sin theta cos phi, sin theta sin phi, cos theta).

Scale of the procedural maps: the irradiance on an upward-facing horizontal surface (:func:`irradiance_up`,
luminance) is pi, so a white Lambertian floor reflects radiance 1 (display white).
"""

from __future__ import annotations

import os
import sys
import warnings

if "cv2" not in sys.modules:  # OpenCV reads this switch once; it must be set before the first import
    os.environ.setdefault("OPENCV_IO_ENABLE_OPENEXR", "1")

from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from simtest.errors import AssetError, ConfigError
from simtest.materials.maps import read_only
from simtest.materials.sky import sky_radiance, studio_radiance
from simtest.materials.sphere import LUMA, directions, solid_angles, up_weights

__all__ = ["Environment", "ENVIRONMENTS", "procedural_environment", "irradiance_up", "environment_files",
           "read_environment", "light_summary", "rotated"]

ENVIRONMENTS: tuple[str, ...] = ("sky", "studio")


@dataclass(frozen=True, eq=False)
class Environment:
    """An environment map.

    Attributes:
        name: ``"sky"``, ``"studio"`` or the file stem.
        radiance: (H, 2H, 3) float32 linear radiance, equirectangular (module docstring), read-only.
    """

    name: str
    radiance: np.ndarray

    def __post_init__(self) -> None:
        r = np.asarray(self.radiance, dtype=np.float32)
        if r.ndim != 3 or r.shape[2] != 3 or r.shape[1] != 2 * r.shape[0] or r.shape[0] < 2:
            raise ConfigError(f"environment {self.name!r}: radiance must have shape (H, 2H, 3), got {r.shape}")
        object.__setattr__(self, "radiance", read_only(r))

    @property
    def height(self) -> int:
        """H, the number of rows."""
        return int(self.radiance.shape[0])


def procedural_environment(kind: str, seed: int, height: int = 128) -> Environment:
    """A seeded procedural environment of :data:`ENVIRONMENTS`, ``height`` rows (even, 16..4096), scaled so
    :func:`irradiance_up` is pi.

    "sky": a clear to hazy sky (blue zenith, brighter horizon, circumsolar glow), a ground of albedo 0.2-0.3
    below the horizon and a sun disk of a few texels at elevation 15-75 deg that gives 70-85 % of the
    horizontal irradiance. "studio": a dark-grey surround, 2-4 rectangular soft boxes (neutral to warm) and a
    floor bounce.

    Raises:
        ConfigError: Unknown kind, bad seed or height.
    """
    if kind not in ENVIRONMENTS:
        raise ConfigError(f"environment kind {kind!r} is unknown; allowed: {', '.join(ENVIRONMENTS)}")
    if isinstance(height, bool) or not isinstance(height, (int, np.integer)) or not 16 <= height <= 4096 \
            or height % 2:
        raise ConfigError(f"environment height {height!r} must be an even integer in [16, 4096]")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ConfigError(f"environment seed {seed!r} must be a non-negative integer")
    return _procedural(kind, int(seed), int(height))


@lru_cache(maxsize=16)
def _procedural(kind: str, seed: int, height: int) -> Environment:
    from simtest.rng import child_sequence

    rng = np.random.default_rng(child_sequence(seed, 100 + ENVIRONMENTS.index(kind)))
    radiance = sky_radiance(rng, height) if kind == "sky" else studio_radiance(rng, height)
    return Environment(kind, radiance)


def irradiance_up(env: Environment) -> float:
    """Irradiance (luminance, Rec. 709 weights) on an upward-facing horizontal surface: the integral of
    L cos(theta) dOmega over the upper hemisphere, exact per texel row."""
    y = env.radiance @ LUMA
    return float((y * up_weights(env.height)[:, None]).sum())


def environment_files(folder: str) -> tuple[str, ...]:
    """The ``.hdr`` and ``.exr`` files directly in ``folder``, as sorted absolute paths.

    Raises:
        ConfigError: ``folder`` is not a folder or holds no such file.
    """
    root = Path(folder)
    if not root.is_dir():
        raise ConfigError(f"environment folder {folder!r} is not a folder")
    found = sorted(str(p.resolve()) for p in root.iterdir()
                   if p.is_file() and p.suffix.lower() in (".hdr", ".exr"))
    if not found:
        raise ConfigError(f"environment folder {folder!r} holds no .hdr or .exr file")
    return tuple(found)


def _imread_float(path: str) -> np.ndarray:
    import cv2

    try:
        img = cv2.imread(path, cv2.IMREAD_ANYDEPTH | cv2.IMREAD_COLOR)
    except cv2.error:
        img = None
    if img is not None:
        return img[..., ::-1]
    if path.lower().endswith(".exr"):
        try:
            import imageio.v3 as iio

            with warnings.catch_warnings():                        # imageio's plugin probing warns
                warnings.simplefilter("ignore")
                img = np.asarray(iio.imread(path), dtype=np.float32)
            return img[..., :3] if img.ndim == 3 else np.repeat(img[..., None], 3, axis=2)
        except Exception as exc:
            raise AssetError(f"environment file {path!r} could not be read: OpenCV did not decode it (its "
                             f"OpenEXR support is missing from this build, or was off because "
                             f"OPENCV_IO_ENABLE_OPENEXR=1 was not set before cv2 was first imported) and "
                             f"imageio failed ({' '.join(str(exc).split())}); convert it to Radiance .hdr, e.g. "
                             f"`oiiotool in.exr -o out.hdr`") from exc
    raise AssetError(f"environment file {path!r} could not be read as a Radiance .hdr image")


def read_environment(path: str, height: int = 256) -> Environment:
    """An ``.hdr`` (Radiance RGBE) or ``.exr`` equirectangular file (same convention as this module), resized
    (area interpolation) to (height, 2 * height); radiance as stored, negative and non-finite values -> 0.

    Raises:
        AssetError: Unreadable file, or not 2:1 within 1 %.
        ConfigError: Bad height.
    """
    if isinstance(height, bool) or not isinstance(height, (int, np.integer)) or not 2 <= height <= 8192:
        raise ConfigError(f"environment height {height!r} must be an integer in [2, 8192]")
    return _read(str(Path(path).resolve()), int(height))


@lru_cache(maxsize=8)
def _read(path: str, height: int) -> Environment:
    import cv2

    if not Path(path).is_file():
        raise AssetError(f"environment file {path!r} does not exist")
    img = np.asarray(_imread_float(path), dtype=np.float32)
    h, w = img.shape[:2]
    if abs(w / h - 2.0) > 0.02:
        raise AssetError(f"environment file {path!r} is {w}x{h} pixels; an equirectangular map must be 2:1 "
                         f"(within 1 %)")
    img = np.where(np.isfinite(img) & (img > 0), img, 0.0).astype(np.float32)
    if (h, w) != (height, 2 * height):
        img = cv2.resize(img, (2 * height, height), interpolation=cv2.INTER_AREA)
    return Environment(Path(path).stem, np.maximum(img, 0.0))


def _light_region(y: np.ndarray, peak: tuple[int, int]) -> np.ndarray:
    """Mask of the texels connected to ``peak`` whose luminance is above a tenth of the peak's (columns wrap)."""
    from scipy import ndimage

    r, c = peak
    w = y.shape[1]
    shift = w // 2 - c
    rolled = np.roll(y, shift, axis=1)
    labels, _ = ndimage.label(rolled >= 0.1 * y[r, c])
    return np.roll(labels == labels[r, w // 2], -shift, axis=1)


def light_summary(env: Environment, max_lights: int = 3, contrast: float = 6.0, max_solid_angle: float = 1.0
                  ) -> tuple[np.ndarray, list[tuple[np.ndarray, np.ndarray]]]:
    """What a rasterizer with an ambient term and a few directional lights can approximate of ``env``.

    Lights are the connected regions around the brightest texels (above a tenth of their peak) whose peak
    luminance exceeds ``contrast`` times the environment's mean luminance and whose solid angle is at most
    ``max_solid_angle`` steradians (a bright floor or an overcast sky stays ambient); each is removed (replaced
    by the mean of a ring around it) before the next is searched.

    Returns:
        (ambient, lights): ``ambient`` the (3,) linear RGB mean diffuse irradiance over all normal directions,
        divided by pi, of what is left after removing the lights (= the solid-angle mean radiance);
        ``lights`` up to ``max_lights`` pairs (unit direction from the scene toward the light, world frame
        (3,); (3,) linear RGB irradiance delivered to a surface facing it), brightest first. Deterministic.
    """
    from scipy import ndimage

    rad = np.array(env.radiance, dtype=np.float64)
    dirs = directions(env.height)
    omega = solid_angles(env.height)[:, None]
    lights = []
    for _ in range(max_lights):
        y = rad @ LUMA
        mean_y = float((y * omega).sum() / (4.0 * np.pi))
        peak = np.unravel_index(int(np.argmax(y)), y.shape)
        if y[peak] <= contrast * max(mean_y, 1e-12):
            break
        mask = _light_region(y, peak)
        if float((omega * mask).sum()) > max_solid_angle:
            break
        rows, cols = np.nonzero(mask)                               # the light's texels only
        power = rad[rows, cols] * omega[rows]                       # L dOmega per texel, RGB
        toward = dirs[rows, cols]
        d = (toward * (power @ LUMA)[:, None]).sum(axis=0)
        d /= np.linalg.norm(d)
        cos = np.clip(toward @ d, 0.0, 1.0)
        lights.append((d.astype(np.float32), (power * cos[:, None]).sum(axis=0).astype(np.float32)))
        ring = ndimage.binary_dilation(mask, iterations=2) & ~mask
        fill = rad[ring].mean(axis=0) if ring.any() else np.zeros(3)
        rad[mask] = np.minimum(fill, rad[mask])
    ambient = (rad * omega[..., None]).sum(axis=(0, 1)) / (4.0 * np.pi)
    return ambient.astype(np.float32), lights


def rotated(env: Environment, azimuth_rad: float) -> Environment:
    """``env`` rotated about +z by ``azimuth_rad`` (counter-clockwise seen from above: what was at azimuth phi
    is at phi + azimuth_rad). Exact column roll for multiples of a column width, linear interpolation between
    the two nearest rolls otherwise."""
    w = env.radiance.shape[1]
    shift = float(azimuth_rad) / (2.0 * np.pi) * w
    base = int(np.floor(shift))
    frac = shift - base
    if abs(frac) < 1e-9 or abs(frac - 1.0) < 1e-9:
        out = np.roll(env.radiance, round(shift) % w, axis=1)
    else:
        a = np.roll(env.radiance, base % w, axis=1)
        b = np.roll(env.radiance, (base + 1) % w, axis=1)
        out = (1.0 - frac) * a + frac * b
    return Environment(env.name, out.astype(np.float32))
