"""Write a corrupted copy of a BOP dataset.

Everything that is ground truth is copied byte-identically: ``camera.json``, ``models/``, ``scene_gt.json``,
``scene_camera.json``, amodal ``mask/`` files and any other file (``manifest.json``, ...). Changed are:

* ``rgb/`` images, when an image corruption or an occlusion is asked (written in the same format and file
  name; JPEG files are re-encoded at quality 95);
* ``depth/`` PNGs, only when a depth-noise preset is asked (same ``depth_scale`` as in ``scene_camera.json``);
* with a paste occlusion (with the default ``objects`` kind cutouts of the dataset's own unoccluded objects,
  :mod:`simtest.corrupt.cutouts`, falling back to noise shapes with a warning when the dataset has none; with
  ``paste`` procedural noise shapes), the ``mask_visib/`` files of occluded instances and ``scene_gt_info.json``
  (``px_count_visib``, ``visib_fract``, ``bbox_visib``): in the occluded copy the visible masks and
  visibility fractions include the pasted occluders, while amodal masks, poses, ``px_count_all`` and
  ``px_count_valid`` (clean depth) are unchanged. ``scene_gt_coco.json``, if present, is copied unchanged and
  so still describes the unoccluded visible masks (``corruption.json`` lists it under ``stale_files``).

``corruption.json`` at the top of the copy records the spec, the seed, the implied parameters and the
achieved occlusion fractions per image. Each image draws from its own generator,
``SeedSequence(seed, spawn_key=(scene_id, im_id))`` (:func:`simtest.rng.child_rng`), so results do not depend
on the processing order, the number of workers or the back end (:mod:`simtest.backend`): a unit of work is one
scene, whose worker writes its files straight into the copy. Every file is written atomically (temporary file +
``os.replace``) and ``corruption.json`` last, so a copy with a ``corruption.json`` is complete; an interrupted
run leaves none and is redone from the start with ``overwrite`` (there is no resume). ``corruption.json``
records the back end and worker count under ``execution``; no other byte depends on them.
"""

from __future__ import annotations

import json
import logging
import os
import shutil
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from simtest.backend import Backend, RunStats, preflight, run_units
from simtest.corrupt.occlusion import update_visible_masks, visibility_stats
from simtest.corrupt.spec import CorruptionSpec
from simtest.errors import ConfigError, DatasetError
from simtest.rng import child_rng
from simtest.io.bop import (decode_depth, encode_depth, encode_image, read_depth, read_image, read_mask, rgb_to_bgr,
                            read_scene_files, scene_dirs)
from simtest.io.files import atomic_write_bytes as _atomic_write
from simtest.io.files import dump_json_keyed, prepare_out_dir

__all__ = ["corrupt_dataset", "depth_png_to_m", "depth_m_to_png", "find_scenes"]

_JPEG_QUALITY = 95


def depth_png_to_m(png: np.ndarray, depth_scale: float) -> np.ndarray:
    """BOP depth PNG values -> metres (0 stays 0), float32; see :func:`simtest.io.bop.decode_depth`."""
    return decode_depth(png, depth_scale)


def depth_m_to_png(depth_m: np.ndarray, depth_scale: float) -> np.ndarray:
    """Metres -> BOP depth PNG values (uint16; missing and out-of-range become 0); see
    :func:`simtest.io.bop.encode_depth`."""
    return encode_depth(depth_m, depth_scale)


def _atomic_copy(src: Path, dst: Path) -> None:
    dst.parent.mkdir(parents=True, exist_ok=True)
    tmp = dst.with_name(f".{dst.name}.tmp{os.getpid()}")
    shutil.copyfile(src, tmp)  # a new file: its mode follows the umask, like every other output
    os.replace(tmp, dst)


def find_scenes(dataset: Path) -> list[Path]:
    """Complete scene folders ``DATASET/<split>/<6 digits>/`` holding a ``scene_camera.json``, sorted."""
    return [scene for split in sorted(p for p in dataset.iterdir() if p.is_dir())
            for scene in scene_dirs(split) if (scene / "scene_camera.json").is_file()]


def corrupt_dataset(in_dir: str | os.PathLike, out_dir: str | os.PathLike, spec: CorruptionSpec, seed: int,
                    overwrite: bool = False, progress: bool = True, backend: Backend | None = None,
                    stats: RunStats | None = None, cutout_fallback: bool = False) -> dict[str, Any]:
    """Write a corrupted copy of the BOP dataset ``in_dir`` to ``out_dir`` (see the module docstring).

    Args:
        in_dir: Source BOP dataset folder (``camera.json``, ``models/``, ``<split>/<scene>/``...).
        out_dir: Destination; must not exist or be empty unless ``overwrite``.
        spec: What to corrupt.
        seed: Non-negative integer seed; image ``(scene_id, im_id)`` uses ``child_rng(seed, scene_id, im_id)``.
        overwrite: Replace the contents of a non-empty ``out_dir``.
        progress: Show a tqdm progress bar.
        backend: Where the scenes run (default: this process); a unit of work is one scene, whose images,
            masks and ``scene_gt_info.json`` its worker writes. The output is the same for every back end and
            worker count but for ``execution`` in ``corruption.json``, which records them.
        stats: Filled with the units finished, retried and failed (:class:`simtest.backend.RunStats`).
        cutout_fallback: With the ``objects`` occlusion kind on a dataset without a usable cutout source (no
            instance at least 95 % visible with its ``mask_visib/`` file, e.g. no masks): paste noise shapes
            instead, with a logged warning, ``occlusion_kind: paste`` and the reason (``occlusion.cutout_fallback``)
            in ``corruption.json``. False (default): that is a :class:`DatasetError`.

    Returns:
        The record written to ``out_dir/corruption.json``.

    Raises:
        DatasetError: Missing or malformed input dataset (scene files are checked by
            :func:`simtest.io.bop.read_scene_files`), a non-empty output without ``overwrite``, or no object
            cutouts for the ``objects`` kind without ``cutout_fallback`` (before anything is written).
        ConfigError: Bad seed or spec.
    """
    if not isinstance(spec, CorruptionSpec):
        raise ConfigError(f"spec must be a CorruptionSpec, got {type(spec).__name__}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise ConfigError(f"seed must be a non-negative integer, got {seed!r}")
    src = Path(in_dir).resolve()
    dst = Path(out_dir).resolve()
    if not src.is_dir():
        raise DatasetError(f"dataset folder {src} does not exist")
    scenes = find_scenes(src)
    if not scenes:
        raise DatasetError(f"no BOP scene folders (<split>/<6-digit scene>/scene_camera.json) found in {src}")
    # Every scene's JSON files are read and validated before anything is written; a split may lack ground truth.
    cache: dict[Path, dict[str, Any]] = {}
    for scene in scenes:
        files = read_scene_files(scene, require_gt=False)
        cache[scene] = {"camera": files.camera, "gt": files.gt or {}, "gt_info": files.gt_info}
        _check_inputs(scene, spec)
    bank, fallback = _cutout_bank(spec, scenes, cutout_fallback)  # a missing source fails before any write
    if fallback is not None:
        spec = replace(spec, occlusion_kind="paste")
    preflight(backend or Backend())  # before the output is touched
    prepare_out_dir(dst, overwrite=overwrite, clear=True, protect=[src], what="output dataset")
    dst.mkdir(parents=True, exist_ok=True)

    units = _scene_units(scenes, cache)
    change_rgb = spec.weather is not None or spec.occlusion is not None
    backend = backend if backend is not None else Backend()
    done = _run_scenes(units, _Setup(src, dst, spec, int(seed), change_rgb, bank), backend,
                       stats if stats is not None else RunStats(), progress)
    produced: set[Path] = set()  # source files whose output was written by the corruption
    occlusion_records: list[dict[str, Any]] = []
    for res in done:  # scene order: the records' order does not depend on the back end
        produced |= res.produced
        occlusion_records += res.records

    # everything else byte-identical
    for root, _dirs, files in os.walk(src):
        for name in files:
            path = Path(root) / name
            if path not in produced:
                _atomic_copy(path, dst / path.relative_to(src))

    record = _record(src, spec, seed, sum(len(u.images) for u in units), change_rgb, occlusion_records)
    if fallback is not None:
        record["occlusion"]["cutout_fallback"] = fallback
    record["execution"] = {"backend": backend.name, "workers": backend.workers}
    _atomic_write(dst / "corruption.json", json.dumps(record, indent=2).encode("utf-8"))
    return record


def _cutout_bank(spec: CorruptionSpec, scenes: list[Path],
                 fallback: bool) -> tuple[list[np.ndarray] | None, str | None]:
    """The object cutouts of the ``objects`` occlusion kind, and why noise shapes replace them (or None).

    A dataset without a usable cutout source raises the :class:`DatasetError` of
    :func:`~simtest.corrupt.cutouts.object_cutouts`, or with ``fallback`` falls back to the ``paste`` kind with
    a logged warning (see :func:`corrupt_dataset`).
    """
    if spec.occlusion is None or spec.occlusion_kind != "objects":
        return None, None
    from simtest.corrupt.cutouts import object_cutouts

    try:
        return object_cutouts(scenes), None
    except DatasetError as exc:
        if not fallback:
            raise
        reason = f"{exc}; pasted noise shapes instead (occlusion kind 'paste')"
        logging.getLogger(__name__).warning("object cutouts unavailable: %s", reason)
        return None, reason


# --- scenes: the units of work ------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Setup:
    """What every worker needs: the (absolute) source and output folders, the spec, the seed, whether RGB
    changes, and the occluder cutouts of the ``objects`` occlusion kind."""

    src: Path
    dst: Path
    spec: CorruptionSpec
    seed: int
    change_rgb: bool
    bank: list[np.ndarray] | None


@dataclass(frozen=True)
class _SceneUnit:
    """One unit of work: a scene folder, its RGB files in name order and its validated JSON (``camera``,
    ``gt``, ``gt_info``); ``index`` is its place in the run."""

    index: int
    scene: Path
    images: tuple[Path, ...]
    meta: dict[str, Any]


@dataclass
class _SceneResult:
    """The source files a scene's outputs replace and its occlusion records, in image order."""

    index: int
    produced: set[Path] = field(default_factory=set)
    records: list[dict[str, Any]] = field(default_factory=list)


#: The setup of the run this process works for (set by :func:`_init_worker` or by the driver).
_SETUP: dict[str, _Setup] = {}


def _scene_units(scenes: list[Path], cache: dict[Path, dict[str, Any]]) -> list[_SceneUnit]:
    """One unit per scene with RGB images, in scene order."""
    units: list[_SceneUnit] = []
    for scene in scenes:
        rgb_dir = scene / "rgb"
        images = tuple(p for p in sorted(rgb_dir.iterdir()) if p.is_file() and p.stem.isdigit()) \
            if rgb_dir.is_dir() else ()
        if images:
            units.append(_SceneUnit(len(units), scene, images, cache[scene]))
    return units


def _init_worker(setup: _Setup) -> None:
    _SETUP["run"] = setup


def _corrupt_scene(unit: _SceneUnit) -> _SceneResult:
    """Corrupt every image of one scene and write its outputs (images, masks, an occluded copy's
    ``scene_gt_info.json``) atomically; each image draws from ``child_rng(seed, scene_id, im_id)``."""
    s = _SETUP["run"]
    out = _SceneResult(unit.index)
    scene = unit.scene
    for rgb_path in unit.images:
        rec = _corrupt_image(s.src, s.dst, scene, rgb_path, int(scene.name), int(rgb_path.stem), unit.meta, s.spec,
                             s.seed, s.change_rgb, out.produced, s.bank)
        if rec is not None:
            out.records.append(rec)
    info_path = scene / "scene_gt_info.json"
    if out.records and unit.meta["gt_info"] is not None:
        _atomic_write(s.dst / info_path.relative_to(s.src), dump_json_keyed(unit.meta["gt_info"]).encode("utf-8"))
        out.produced.add(info_path)
    return out


def _run_scenes(units: list[_SceneUnit], setup: _Setup, backend: Backend, stats: RunStats,
                progress: bool) -> list[_SceneResult]:
    """Run the scene units on ``backend`` with one progress bar over images; the results in scene order."""
    from tqdm import tqdm

    in_process = backend.in_process(len(units))
    done: dict[int, _SceneResult] = {}
    bar = tqdm(total=sum(len(u.images) for u in units), desc=f"corrupt {setup.spec.label()}", unit="img",
               disable=not progress)
    if in_process:
        _init_worker(setup)
    try:
        for res in run_units(_corrupt_scene, units, backend, init=_init_worker,
                             init_args=() if in_process else (setup,), stats=stats):
            done[res.index] = res
            bar.update(len(units[res.index].images))
    finally:
        bar.close()
        if in_process:
            _SETUP.clear()
    return [done[i] for i in range(len(units))]


def _record(src: Path, spec: CorruptionSpec, seed: int, images: int, change_rgb: bool,
            occlusion_records: list[dict[str, Any]]) -> dict[str, Any]:
    """The provenance written to ``corruption.json``: source, seed, RNG scheme, what changed, occlusion stats."""
    from simtest import __version__

    record: dict[str, Any] = {
        "simtest_version": __version__,
        "source": str(src),
        "seed": int(seed),
        "rng": "per image: numpy SeedSequence(seed, spawn_key=(scene_id, im_id)); spec.apply spawns 3 children "
               "(occlusion, image, depth)",
        **spec.describe(),
        "images": images,
        "modified": (["rgb"] if change_rgb else []) + (["depth"] if spec.depth_noise is not None else [])
                    + (["mask_visib", "scene_gt_info.json"] if spec.occlusion is not None else []),
        "stale_files": (["scene_gt_coco.json"] if spec.occlusion is not None else []),
    }
    if spec.occlusion is not None and occlusion_records:
        fg = np.array([r["fg_fraction"] for r in occlusion_records])
        bg = np.array([r["bg_fraction"] for r in occlusion_records])
        record["occlusion"].update({
            "mean_fg_fraction": float(fg.mean()), "mean_bg_fraction": float(bg.mean()),
            "in_band_fraction": float(np.mean([r["in_band"] for r in occlusion_records])),
            "per_image": occlusion_records,
        })
    return record


def _check_inputs(scene: Path, spec: CorruptionSpec) -> None:
    """Refuse, before anything is written, depth noise on a scene without ``depth/`` (a real BOP test excerpt
    may ship RGB only; weather needs only ``rgb/``)."""
    if spec.depth_noise is not None and not (scene / "depth").is_dir():
        raise DatasetError(f"{scene} has no depth/ folder: depth noise {spec.depth_noise!r} needs depth images")


def _corrupt_image(src: Path, dst: Path, scene: Path, rgb_path: Path, scene_id: int, im_id: int,
                   meta: dict[str, Any], spec: CorruptionSpec, seed: int, change_rgb: bool,
                   produced: set[Path], bank: list[np.ndarray] | None = None) -> dict[str, Any] | None:
    cam = meta["camera"].get(str(im_id))
    if cam is None:
        raise DatasetError(f"image id {im_id} of {rgb_path} has no entry in {scene / 'scene_camera.json'}")
    K = np.asarray(cam["cam_K"], dtype=np.float64).reshape(3, 3) if "cam_K" in cam else None
    rgb = read_image(scene, im_id)
    h, w = rgb.shape[:2]

    depth = None
    depth_path = scene / "depth" / f"{im_id:06d}.png"
    depth_scale = float(cam.get("depth_scale", 1.0))
    if spec.depth_noise is not None:
        if not depth_path.is_file():
            raise DatasetError(f"depth noise asked but {depth_path} is missing")
        depth = read_depth(scene, im_id, depth_scale)

    visib_paths: list[Path] = []
    masks = None
    if spec.occlusion is not None:
        n_gt = len(meta["gt"].get(str(im_id), []))
        visib_paths = [scene / "mask_visib" / f"{im_id:06d}_{g:06d}.png" for g in range(n_gt)]
        masks = [read_mask(scene, im_id, g) if p.is_file() else np.zeros((h, w), bool)
                 for g, p in enumerate(visib_paths)]

    rng = child_rng(seed, scene_id, im_id)
    out_rgb, out_depth, occ, info = spec.apply_with_info(rgb, depth, masks if masks is not None else [], rng, K,
                                                         occluder_bank=bank)

    if change_rgb:
        _atomic_write(dst / rgb_path.relative_to(src),
                      encode_image(rgb_to_bgr(out_rgb), rgb_path.suffix,
                                   jpg_quality=_JPEG_QUALITY))
        produced.add(rgb_path)
    if spec.depth_noise is not None:
        _atomic_write(dst / depth_path.relative_to(src), encode_image(encode_depth(out_depth, depth_scale)))
        produced.add(depth_path)
    if spec.occlusion is None:
        return None

    new_masks = update_visible_masks(masks, occ) if masks else []
    infos = meta["gt_info"].get(str(im_id)) if meta["gt_info"] is not None else None
    for g, (p, old, new) in enumerate(zip(visib_paths, masks, new_masks)):
        if p.is_file() and not np.array_equal(old, new):
            _atomic_write(dst / p.relative_to(src), encode_image(new.astype(np.uint8) * 255, mask=True))
            produced.add(p)
        if infos is not None and g < len(infos):
            infos[g].update(visibility_stats(new, int(infos[g].get("px_count_all", 0))))
    assert info is not None
    return {"scene_id": scene_id, "im_id": im_id, "split": scene.parent.name, **{
        k: info[k] for k in ("fg_fraction", "bg_fraction", "in_band", "n_occluders")}}
