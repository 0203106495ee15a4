"""A template bank: one object rendered over its viewing sphere, each view cropped and encoded, cached on disk.

Per view ``i`` the bank holds the encoder's unit cell features ``feats[i]`` (C, h, w) float16, the fraction of
each cell the object covers ``masks[i]`` (h, w), and the view's pose in its crop camera: rotation ``R[i]``,
translation ``t[i]`` (metres) and crop intrinsics ``K[i]`` (pixels). Views are a Fibonacci lattice of the
sphere (:func:`~simtest.estimators.templates.views.sphere_directions`) at and above ``min_elevation_deg``, the
object upright (in-plane angle 0) at ``distance`` metres, its diameter spanning ``fill`` of the render.

Banks are cached as ``.npz`` files in ``<cache>/templates/`` (:func:`simtest.objects.cache.cache_dir`), keyed by
the mesh hash, the appearance and every setting; a second build with the same key reads the file.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np

from simtest.errors import ConfigError
from simtest.estimators.templates.crops import region_crop
from simtest.estimators.templates.encoder import FeatureEncoder
from simtest.estimators.templates.render import ObjectRenderer
from simtest.estimators.templates.views import sphere_directions, view_rotation
from simtest.objects.cache import cache_dir

__all__ = ["BankSettings", "TemplateBank", "build_bank", "render_intrinsics", "render_templates", "template_image", "load_or_build", "bank_path", "FORMAT"]

#: Version of the bank file; a change of what a bank holds or how it is made bumps it.
FORMAT = "simtest-templates/1"
RENDER_SIZE = 256


@dataclass(frozen=True)
class BankSettings:
    """How a bank is made: ``views`` lattice points of the whole sphere, kept at and above
    ``min_elevation_deg`` (degrees); crops of ``size`` pixels (a multiple of 32) with side ``margin`` times
    the object's box; features at ``stride`` pixels; the object at ``distance`` metres filling ``fill`` of a
    256-pixel render, on a ``background`` grey level."""

    views: int = 600
    min_elevation_deg: float = -20.0
    size: int = 128
    margin: float = 1.2
    stride: int = 8
    distance: float = 1.0
    fill: float = 0.6
    #: Grey level (0-255) behind the object in a template: 0 (black) hides the object's dark parts against it,
    #: which a real background does not.
    background: int = 0

    def check(self) -> None:
        if int(self.size) % 32 or int(self.size) < 32:
            raise ConfigError(f"templates: crop size must be a positive multiple of 32 pixels, got {self.size!r}")
        if not 0 <= int(self.background) <= 255:
            raise ConfigError(f"templates: background must be a grey level in 0-255, got {self.background!r}")
        if int(self.views) < 2 or not self.distance > 0 or not 0 < self.fill <= 1 or not self.margin >= 1:
            raise ConfigError(f"templates: need views >= 2, distance > 0, 0 < fill <= 1, margin >= 1, got "
                              f"{self.views!r}, {self.distance!r}, {self.fill!r}, {self.margin!r}")


@dataclass(frozen=True)
class TemplateBank:
    """One object's templates (see the module doc); arrays indexed by view."""

    feats: np.ndarray
    masks: np.ndarray
    R: np.ndarray
    t: np.ndarray
    K: np.ndarray
    directions: np.ndarray
    settings: BankSettings

    def __len__(self) -> int:
        return len(self.R)


def _appearance_hash(obj) -> str:
    app = getattr(obj, "appearance", None)
    h = hashlib.sha1()
    for name in ("texture", "face_uv", "vertex_colors", "face_colors"):
        arr = None if app is None else getattr(app, name, None)
        h.update(name.encode() + (b"-" if arr is None else np.ascontiguousarray(arr).tobytes()))
    h.update(json.dumps([float(c) for c in obj.rgba]).encode())
    return h.hexdigest()[:16]


def bank_path(obj, settings: BankSettings, folder: Path | None = None) -> Path:
    """The cache file of ``obj``'s bank with ``settings`` (in ``folder``, default ``<cache>/templates``)."""
    fields = asdict(settings)
    if not fields["background"]:  # banks made before the setting existed keep their files
        del fields["background"]
    key = json.dumps({"format": FORMAT, "mesh": obj.mesh_hash, "appearance": _appearance_hash(obj), **fields},
                     sort_keys=True)
    digest = hashlib.sha1(key.encode()).hexdigest()[:20]
    return (folder or cache_dir() / "templates") / f"{obj.name}_{digest}.npz"


def render_intrinsics(obj, settings: BankSettings) -> np.ndarray:
    """Intrinsics (pixels) of the 256-pixel template render: ``obj`` at ``distance`` spans ``fill`` of it."""
    f = settings.fill * RENDER_SIZE * float(settings.distance) / max(float(obj.diameter), 1e-6)
    c = (RENDER_SIZE - 1) / 2.0
    return np.array([[f, 0.0, c], [0.0, f, c], [0.0, 0.0, 1.0]])


def template_image(renderer: ObjectRenderer, R: np.ndarray, settings: BankSettings) -> tuple[np.ndarray, np.ndarray]:
    """The object of ``renderer`` at rotation ``R`` (model to camera), ``distance`` metres down the optical axis:
    RGB (H, W, 3) uint8 on the ``background`` grey level, and its mask (H, W) bool."""
    rgb, mask = renderer.render(R, np.array([0.0, 0.0, float(settings.distance)]))
    if settings.background:
        rgb[~mask] = int(settings.background)
    return rgb, mask


def render_templates(renderer: ObjectRenderer, rotations: np.ndarray, settings: BankSettings,
                     encoder: FeatureEncoder, directions: np.ndarray | None = None) -> TemplateBank:
    """Templates of the object of ``renderer`` (made with :func:`render_intrinsics`) at ``rotations`` (n, 3, 3),
    model to camera, at ``distance`` on the optical axis: rendered, cropped and encoded."""
    S, D = int(settings.size), float(settings.distance)
    K_r = renderer.K
    crops, Rs, ts, Ks = [], [], [], []
    for R in rotations:
        t = np.array([0.0, 0.0, D])
        rgb, mask = template_image(renderer, R, settings)
        crop = region_crop(rgb, mask, K_r, S, settings.margin)
        crops.append((crop.rgb, crop.mask))
        Rs.append(crop.R_virt @ R)
        ts.append(crop.R_virt @ t)
        Ks.append(crop.K)
    feats = encoder.features(np.stack([c[0] for c in crops]))
    h, w = feats.shape[-2:]
    masks = np.stack([cv2.resize(c[1].astype(np.float32), (w, h), interpolation=cv2.INTER_AREA) for c in crops])
    dirs = np.zeros((len(Rs), 3)) if directions is None else directions
    return TemplateBank(feats=feats.astype(np.float16), masks=masks.astype(np.float32), R=np.stack(Rs),
                        t=np.stack(ts), K=np.stack(Ks), directions=dirs, settings=settings)


def build_bank(obj, settings: BankSettings, encoder: FeatureEncoder) -> TemplateBank:
    """Render, crop and encode ``obj``'s views (see the module doc)."""
    settings.check()
    dirs = sphere_directions(settings.views, settings.min_elevation_deg)
    with ObjectRenderer(obj, render_intrinsics(obj, settings), RENDER_SIZE, RENDER_SIZE) as renderer:
        return render_templates(renderer, np.stack([view_rotation(d) for d in dirs]), settings, encoder, dirs)


def load_or_build(obj, settings: BankSettings, encoder: FeatureEncoder, folder: Path | None = None
                  ) -> TemplateBank:
    """``obj``'s bank from the cache, or built (:func:`build_bank`) and written there atomically."""
    path = bank_path(obj, settings, folder)
    if path.is_file():
        with np.load(path) as z:
            return TemplateBank(feats=z["feats"], masks=z["masks"], R=z["R"], t=z["t"], K=z["K"],
                                directions=z["directions"], settings=settings)
    bank = build_bank(obj, settings, encoder)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp.npz")
    np.savez(tmp, feats=bank.feats, masks=bank.masks, R=bank.R, t=bank.t, K=bank.K, directions=bank.directions)
    tmp.replace(path)
    return bank
