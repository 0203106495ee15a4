"""Ground-truth masks of a BOP dataset that ships none, rendered from its poses and models.

Real BOP excerpts and some test sets come without ``mask/`` and ``mask_visib/``. This module renders them
as the BOP toolkit's ``calc_gt_masks`` does, with simtest's exact z-buffer
(:func:`simtest.render.zbuffer.render_depth`, pixel centres, planar depth in metres):

* ``mask``: the pixels the model covers at its ground-truth pose (amodal).
* ``mask_visib``, when the scene has ``depth/``: the BOP19 rule on distances (not planar depth): a covered
  pixel is visible where the model's distance is at most the measured distance plus ``delta_m`` (15 mm as in
  the toolkit) or where the sensor measured nothing.
* ``mask_visib`` without depth: the covered pixels where this model is the nearest of the *annotated*
  objects (occlusion by unannotated clutter is not seen; the report says so).

The dataset's ``scene_gt_info.json`` is kept as distributed. Output goes either into the dataset's scene
folders (in place) or into a new dataset folder whose other files are symbolic links to the original, so a
read-only download is never written to.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from simtest.errors import ConfigError, DatasetError
from simtest.io.bop import read_depth, read_image, read_json, read_scene
from simtest.io.files import write_new_file
from simtest.io.bop_splits import dataset_split_dir, scene_dirs
from simtest.io.png import encode_mask_png
from simtest.render.zbuffer import depth_to_distance, render_depth

__all__ = ["GTMaskReport", "visible_masks", "write_gt_masks", "BOP_VISIB_DELTA_M"]

#: The BOP toolkit's visibility tolerance of ``calc_gt_masks`` (metres, on distances).
BOP_VISIB_DELTA_M = 0.015

Mesh = tuple[np.ndarray, np.ndarray]


@dataclass
class GTMaskReport:
    """What :func:`write_gt_masks` wrote."""

    out_dir: Path
    images: int = 0
    masks: int = 0
    #: Scenes whose visibility came from measured depth (the BOP rule); the others used the annotated
    #: objects only.
    with_depth: list[int] = field(default_factory=list)
    without_depth: list[int] = field(default_factory=list)

    def summary(self) -> str:
        how = []
        if self.with_depth:
            how.append(f"{len(self.with_depth)} scene(s) with measured depth (BOP19 rule, delta "
                       f"{BOP_VISIB_DELTA_M * 1000:.0f} mm)")
        if self.without_depth:
            how.append(f"{len(self.without_depth)} scene(s) without depth (visibility among the annotated "
                       "objects only: unannotated clutter is not seen)")
        return f"wrote {self.masks} masks of {self.images} images to {self.out_dir}: " + "; ".join(how)


def visible_masks(depths: list[np.ndarray], K: np.ndarray, measured_m: np.ndarray | None = None,
                  delta_m: float = BOP_VISIB_DELTA_M) -> list[np.ndarray]:
    """Visible masks of objects from their rendered planar depths (metres, 0 = not covered).

    Args:
        depths: Per object its rendered depth (H, W), metres.
        K: 3x3 intrinsics (pixels), to turn depth into distance along each pixel's ray as the toolkit does.
        measured_m: The sensor's planar depth (H, W), metres, 0 = no reading; None: visibility among the
            given objects only (a pixel belongs to the nearest object covering it).
        delta_m: Tolerance of the measured-depth test (metres).

    Returns:
        Per object a bool (H, W) mask.
    """
    if not depths:
        return []
    if measured_m is not None:
        d_meas = depth_to_distance(np.asarray(measured_m, np.float64), K)
        out = []
        for d in depths:
            d_obj = depth_to_distance(np.asarray(d, np.float64), K)
            cov = d_obj > 0
            out.append(cov & ((d_meas == 0) | (d_obj <= d_meas + delta_m)))
        return out
    stack = np.stack([np.where(d > 0, d, np.inf) for d in depths])
    nearest = np.argmin(stack, axis=0)
    covered = np.isfinite(stack.min(axis=0))
    return [covered & (nearest == k) for k in range(len(depths))]


def _link_tree(src: Path, dst: Path, skip: set[str]) -> None:
    """``dst`` holds a symbolic link to every entry of ``src`` except the names in ``skip``."""
    dst.mkdir(parents=True, exist_ok=True)
    for entry in sorted(src.iterdir()):
        if entry.name not in skip and not (dst / entry.name).exists():
            os.symlink(entry.resolve(), dst / entry.name)


def _scene_masks(scene_dir: Path, out_scene: Path, meshes: Mapping[int, Mesh], delta_m: float,
                 tick: Callable[[], None]) -> tuple[int, int, bool]:
    """Render one scene's masks into ``out_scene/mask{,_visib}`` (written to ``*.partial`` folders and
    renamed, so an interrupted run leaves no half folder). Returns (images, masks, used depth)."""
    images = read_scene(scene_dir)
    has_depth = (scene_dir / "depth").is_dir()
    parts = {sub: out_scene / f"{sub}.partial" for sub in ("mask", "mask_visib")}
    for p in parts.values():
        shutil.rmtree(p, ignore_errors=True)
        p.mkdir(parents=True)
    n_masks = 0
    size: tuple[int, int] | None = None
    for im_id, im in sorted(images.items()):
        if size is None:
            size = read_image(scene_dir, im_id).shape[:2]
        h, w = size
        depths = []
        for g in im["gt"]:
            if g.obj_id not in meshes:
                raise DatasetError(f"{scene_dir}/scene_gt.json: image {im_id} annotates obj_id {g.obj_id}, which "
                                   f"has no model (models: {sorted(meshes)})")
            V, F = meshes[g.obj_id]
            depths.append(render_depth(V, F, g.T_cam_obj.R, g.T_cam_obj.t, im["K"], w, h))
        measured = read_depth(scene_dir, im_id, im["depth_scale"]) if has_depth else None
        for k, (d, vis) in enumerate(zip(depths, visible_masks(depths, im["K"], measured, delta_m))):
            name = f"{im_id:06d}_{k:06d}.png"
            write_new_file(parts["mask"] / name, encode_mask_png(d > 0))
            write_new_file(parts["mask_visib"] / name, encode_mask_png(vis))
            n_masks += 1
        tick()
    for sub, p in parts.items():
        p.rename(out_scene / sub)
    return len(images), n_masks, has_depth


def write_gt_masks(dataset_dir: str | Path, meshes: Mapping[int, Mesh], out_dir: str | Path | None = None,
                   split: str | None = None, overwrite: bool = False, delta_m: float = BOP_VISIB_DELTA_M,
                   progress: bool = True) -> GTMaskReport:
    """Render ``mask/`` and ``mask_visib/`` for every annotated image of a dataset split.

    Args:
        dataset_dir: BOP dataset root.
        meshes: Per ``obj_id`` its model ``(vertices (N, 3) metres, faces (M, 3))``.
        out_dir: None: write into the dataset's scene folders. Else a new dataset folder: every other file
            and folder of the dataset is a symbolic link to the original.
        split: The split (None: the only one, see :func:`simtest.io.bop_splits.resolve_split`).
        overwrite: Replace existing mask folders (else they are an error, naming the folder).
        delta_m: Visibility tolerance against measured depth (metres).
        progress: Show a progress bar with ETA.

    Raises:
        DatasetError: Missing files, an annotated object without a model.
        ConfigError: Existing masks without ``overwrite``, or ``out_dir`` inside the dataset.
    """
    root = Path(dataset_dir)
    split_dir = dataset_split_dir(root, split)
    scenes = scene_dirs(split_dir)
    out_root = root if out_dir is None else Path(out_dir)
    if out_dir is not None and out_root.resolve().is_relative_to(root.resolve()):
        raise ConfigError(f"--out {out_root} lies inside the dataset {root}; give a folder outside it (or no --out "
                          "to write the masks into the dataset itself)")
    targets = [out_root / split_dir.name / s.name for s in scenes]
    existing = [t / sub for t in targets for sub in ("mask", "mask_visib") if (t / sub).exists()]
    if existing and not overwrite:
        raise ConfigError(f"{existing[0]} exists ({len(existing)} mask folder(s) in all); pass --overwrite to "
                          "replace them")
    if out_dir is not None:
        _link_tree(root, out_root, {split_dir.name})
        for s, t in zip(scenes, targets):
            _link_tree(s, t, {"mask", "mask_visib"})
    n_images = sum(len(read_json(s / "scene_gt.json")) for s in scenes)
    from tqdm import tqdm

    report = GTMaskReport(out_root)
    with tqdm(total=n_images, desc="masks", unit="image", disable=not progress) as bar:
        for s, t in zip(scenes, targets):
            for sub in ("mask", "mask_visib"):
                if (t / sub).exists():
                    shutil.rmtree(t / sub)
            n_im, n_m, depth = _scene_masks(s, t, meshes, delta_m, lambda: bar.update(1))
            report.images += n_im
            report.masks += n_m
            (report.with_depth if depth else report.without_depth).append(int(s.name))
    return report
