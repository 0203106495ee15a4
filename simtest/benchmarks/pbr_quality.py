"""Quality against cost of the ``pbr`` profile's settings: PSNR against a high-sample reference of the same views.

:func:`bench_pbr_quality` builds and settles scenes as ``simtest generate --profile pbr`` does (object set
``builtin``, the looks on), renders a few views of each with a reference setting (``reference_spp`` samples,
the default sampler, guides and denoiser: the reference's own noise is then far below the settings'), and the
same views with every compared setting, interleaved view by view so that a load drifting on the machine weighs
on all settings alike. Each setting's row: samples per pixel, wall and CPU seconds per frame of the renderer
(first view of each setting and scene not counted: kernel look-up), its stages, and the PSNR (dB) of the 8-bit
image against the reference's, mean and range over the views. References are cached under ``cache`` (keyed by
size, scene, view, samples and seed) so that runs comparing other settings reuse them.
"""

from __future__ import annotations

import dataclasses
import os
import time
from pathlib import Path

import numpy as np

__all__ = ["PbrSetting", "QualityRow", "QualityBench", "bench_pbr_quality", "BEFORE", "DEFAULT",
           "parse_setting", "previous_auto_spp"]


def previous_auto_spp(width: int, height: int) -> int:
    """Samples per pixel of ``render.pbr_spp = "auto"`` before this release: ``round(16 * sqrt(320 * 240 /
    pixels))`` clamped to [8, 16] (16 at 320x240, 8 at 640x480)."""
    return int(np.clip(round(16.0 * np.sqrt(320 * 240 / max(1, int(width) * int(height)))), 8, 16))


@dataclasses.dataclass(frozen=True)
class PbrSetting:
    """One compared setting of :class:`simtest.render.pbr.PbrRenderer`.

    Attributes:
        name: Its label in the table.
        spp: Samples per pixel: an integer, ``"auto"`` (this release's rule) or ``"previous"``
            (:func:`previous_auto_spp`).
        sampler, guide_spp, denoise_quality: As the renderer's arguments.
        freeze: Replay recorded kernels for the views of a scene (:attr:`PbrRenderer.freeze`).
    """

    name: str
    spp: int | str = "auto"
    sampler: str = "multijitter"
    guide_spp: int = 4
    denoise_quality: str = "fast"
    freeze: bool = True

    def samples(self, width: int, height: int) -> int:
        from simtest.render.pbr import auto_spp

        if self.spp == "auto":
            return auto_spp(width, height)
        if self.spp == "previous":
            return previous_auto_spp(width, height)
        return int(self.spp)


#: The earlier default: independent samples, the previous spp rule, one-sample guides, OIDN ``high``, every view
#: traced anew.
BEFORE = PbrSetting("before", spp="previous", sampler="independent", guide_spp=1, denoise_quality="high",
                    freeze=False)
#: This release's default.
DEFAULT = PbrSetting("default")


def parse_setting(text: str) -> PbrSetting:
    """``NAME`` (``before`` / ``default``) or ``NAME:key=value,key=value`` with keys ``spp``, ``sampler``,
    ``guide_spp``, ``denoise_quality``, ``freeze`` (``0`` / ``1``); keys not given keep :data:`DEFAULT`'s values.

    Raises:
        ConfigError: Naming the bad key or value.
    """
    from simtest.errors import ConfigError
    from simtest.render.pbr import DENOISE_QUALITIES, SAMPLERS

    name, _, rest = text.partition(":")
    if not rest and name in ("before", "default"):
        return BEFORE if name == "before" else DEFAULT
    out: dict = {}
    for kv in filter(None, rest.split(",")):
        key, _, value = kv.partition("=")
        if key == "spp":
            if value not in ("auto", "previous") and not (value.isdigit() and int(value) >= 1):
                raise ConfigError(f"setting {text!r}: spp={value!r}; allowed: auto, previous or an integer >= 1")
            out[key] = value if value in ("auto", "previous") else int(value)
        elif key == "guide_spp":
            if not (value.isdigit() and int(value) >= 1):
                raise ConfigError(f"setting {text!r}: guide_spp={value!r}; allowed: an integer >= 1")
            out[key] = int(value)
        elif key == "freeze":
            if value not in ("0", "1"):
                raise ConfigError(f"setting {text!r}: freeze={value!r}; allowed: 0 or 1")
            out[key] = value == "1"
        elif key in ("sampler", "denoise_quality"):
            allowed = SAMPLERS if key == "sampler" else DENOISE_QUALITIES
            if value not in allowed:
                raise ConfigError(f"setting {text!r}: {key}={value!r}; allowed: {', '.join(allowed)}")
            out[key] = value
        else:
            raise ConfigError(f"setting {text!r}: unknown key {key!r}; allowed: spp, sampler, guide_spp, "
                              f"denoise_quality, freeze")
    if not name:
        raise ConfigError(f"setting {text!r} has no name (NAME:key=value,...)")
    return PbrSetting(name, **out)


@dataclasses.dataclass
class QualityRow:
    """One setting at one image size: samples, seconds per frame (wall, CPU), stages, PSNR per view (dB)."""

    setting: PbrSetting
    width: int
    height: int
    spp: int
    wall: float
    cpu: float
    stages: dict[str, float]
    psnr: list[float]

    def to_dict(self) -> dict:
        d = dataclasses.asdict(self)
        d["psnr_mean"] = float(np.mean(self.psnr))
        return d


@dataclasses.dataclass
class QualityBench:
    """Rows of :func:`bench_pbr_quality` with the run's reference samples, scenes and views."""

    rows: list[QualityRow]
    reference_spp: int
    scenes: int
    views: int
    load_average: tuple[float, float, float]

    def table(self) -> str:
        lines = [f"pbr settings against a {self.reference_spp}-spp reference of the same views ({self.scenes} scenes "
                 f"x {self.views} views; looks on; load average {self.load_average[0]:.2f} at the start)", "",
                 "| setting | image size | spp | sampler | guide spp | denoiser | frozen | s/frame (wall) | "
                 "CPU s/frame | trace | guides | denoise | PSNR dB (mean) | PSNR dB (min - max) |",
                 "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        for r in self.rows:
            s = r.setting
            lines.append(f"| {s.name} | {r.width}x{r.height} | {r.spp} | {s.sampler} | {min(s.guide_spp, r.spp)} | "
                         f"{s.denoise_quality} | {'yes' if s.freeze else 'no'} | {r.wall:.3f} | {r.cpu:.3f} | {r.stages.get('trace', 0):.3f} | "
                         f"{r.stages.get('guides', 0):.3f} | {r.stages.get('denoise', 0):.3f} | "
                         f"{np.mean(r.psnr):.2f} | {min(r.psnr):.2f} - {max(r.psnr):.2f} |")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        return {"kind": "pbr_quality", "reference_spp": self.reference_spp, "scenes": self.scenes,
                "views": self.views, "load_average": list(self.load_average),
                "rows": [r.to_dict() for r in self.rows]}


def psnr(image: np.ndarray, reference: np.ndarray) -> float:
    """PSNR (dB) of an 8-bit image against an 8-bit reference of the same shape (99 when equal)."""
    mse = float(np.mean((image.astype(np.float64) - reference.astype(np.float64)) ** 2))
    return 99.0 if mse == 0.0 else float(10.0 * np.log10(255.0 ** 2 / mse))


def _renderer(cfg, scene, setting: PbrSetting | None, spp: int):
    from simtest.generators.recorder import pbr_renderer

    s = setting or DEFAULT
    r = pbr_renderer(cfg.replace(**{"render.pbr_spp": int(spp), "render.pbr_sampler": s.sampler,
                                    "render.pbr_guide_spp": int(s.guide_spp),
                                    "render.pbr_denoise_quality": s.denoise_quality}), scene)
    r.freeze = s.freeze
    return r


def bench_pbr_quality(settings: list[PbrSetting], sizes: list[tuple[int, int]], scenes: int = 2, views: int = 3,
                      reference_spp: int = 512, cache: str | os.PathLike | None = None, seed: int = 0,
                      objects: str = "builtin", objects_per_scene: int = 10) -> QualityBench:
    """Render ``views`` views of ``scenes`` scenes at each size with every setting and a ``reference_spp`` reference
    (see the module docstring); the renderer's seed differs between a setting's views and the reference's."""
    from simtest.generators.config import GenerateConfig
    from simtest.generators.pipeline import load_objects, prepare_scene
    from simtest.generators.recorder import scene_cameras
    from simtest.render.pbr_stages import StageTimes

    load = os.getloadavg()
    cache_dir = Path(cache) if cache is not None else None
    rows = []
    for w, h in sizes:
        cfg = GenerateConfig().replace(**{
            "objects": objects, "scenes": scenes, "frames_per_scene": views, "camera.width": w, "camera.height": h,
            "scene.objects_per_scene": [objects_per_scene, objects_per_scene], "render.profile": "pbr",
            "seed": seed})
        objs = load_objects(cfg)
        acc = {s.name: {"wall": [], "cpu": [], "psnr": [], "stages": StageTimes()} for s in settings}
        for sid in range(scenes):
            scene, *_ = prepare_scene(cfg, objs, sid)
            cams = [c for c, _ in scene_cameras(cfg, scene)][:views]
            refs = [_reference(cfg, scene, sid, k, cam, reference_spp, cache_dir) for k, cam in enumerate(cams)]
            renderers = {s.name: _renderer(cfg, scene, s, s.samples(w, h)) for s in settings}
            for s in settings:  # warm-up: the kernel look-up of each setting, not counted
                scene.set_camera(cams[0])
                renderers[s.name].render(scene.data, scene.camera_id, seed=1)
                renderers[s.name].stages = StageTimes()
            for k, cam in enumerate(cams):
                scene.set_camera(cam)
                for s in settings:
                    c0, t0 = time.process_time(), time.perf_counter()
                    img = renderers[s.name].render(scene.data, scene.camera_id, seed=1000 + k).rgb
                    a = acc[s.name]
                    a["wall"].append(time.perf_counter() - t0)
                    a["cpu"].append(time.process_time() - c0)
                    a["psnr"].append(psnr(img, refs[k]))
            for s in settings:
                acc[s.name]["stages"].add(renderers[s.name].stages)
                renderers[s.name].close()
        for s in settings:
            a = acc[s.name]
            rows.append(QualityRow(s, w, h, s.samples(w, h), float(np.mean(a["wall"])), float(np.mean(a["cpu"])),
                                   {k: round(v, 4) for k, v in a["stages"].per_frame().items()},
                                   [round(p, 3) for p in a["psnr"]]))
    return QualityBench(rows, int(reference_spp), scenes, views, load)


def _reference(cfg, scene, sid: int, k: int, cam, spp: int, cache_dir: Path | None) -> np.ndarray:
    """The reference image (8-bit RGB) of view ``k`` of scene ``sid``, from ``cache_dir`` when rendered before."""
    w, h = cfg.camera.width, cfg.camera.height
    path = cache_dir / f"ref_{w}x{h}_seed{cfg.seed}_s{sid}_v{k}_{spp}spp.npy" if cache_dir is not None else None
    if path is not None and path.exists():
        return np.load(path)
    scene.set_camera(cam)
    r = _renderer(cfg, scene, None, spp)
    img = r.render(scene.data, scene.camera_id, seed=7).rgb
    r.close()
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_suffix(".tmp.npy")
        np.save(tmp, img)
        os.replace(tmp, path)
    return img
