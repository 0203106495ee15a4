"""Pictures of a BOP dataset's ground truth, image by image (what ``simtest show DATASET`` draws).

Per image (a *card*): the RGB with, per instance, its visible-mask contour (solid), its amodal-mask contour
(dashed), its 3D bounding box and model axes projected from the ground-truth pose (``K (R x + t)``, OpenCV
camera frame, metres) and a label ``[gt_id] name v=visib_fract``; beside it the depth colourized (holes
black); under them the dense channels the scene folder holds (instances, coords, normals, flow, at half
size) and the scene's referring expressions (``scene_captions.json``) when present.

Any BOP scenewise dataset read by :mod:`simtest.io` works; the models come from ``DATASET/models`` (or the
manifest's object set) through :func:`simtest.objects.loaders.load_dataset_objects`.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from simtest.errors import ConfigError, DatasetError
from simtest.io import bop
from simtest.io.dataset import ImageRef, select_images
from simtest.viz.channels import colourize_depth, dense_panels
from simtest.viz.draw import (box_corner_pixels, draw_axes, draw_box, draw_label, draw_mask_contour, palette,
                              to_canvas)
from simtest.viz.sheet import hstack, legend_strip, text_strip, titled, upscale, upscale_factor, vstack

__all__ = ["ImageSelection", "select_show_images", "draw_instance_gt", "gt_canvas", "dataset_card",
           "load_captions", "axis_length", "DATASET_LEGEND"]

#: The legend of a dataset card: (colour, label, style).
DATASET_LEGEND = [((235, 235, 235), "visible mask", "solid"), ((235, 235, 235), "amodal mask", "dashed"),
                  ((235, 235, 235), "3D box (GT pose)", "box"), ((230, 30, 30), "x", "solid"),
                  ((30, 200, 30), "y", "solid"), ((40, 90, 255), "z", "solid")]


@dataclass(frozen=True)
class ImageSelection:
    """Which images to show: ``split`` (None: the dataset's only split), ``scene`` (None: every scene),
    ``image`` (one image id, None: any) and at most ``count`` images."""

    split: str | None = None
    scene: int | None = None
    image: int | None = None
    count: int = 4


def select_show_images(dataset_dir: Path, sel: ImageSelection, obj_ids: Sequence[int]) -> list[ImageRef]:
    """The images of ``sel``, in scene and image order, with their validated ground truth.

    Raises:
        ConfigError: A scene or image id that is not in the split (the ids there are named), ``count`` < 1.
        DatasetError: Not a BOP dataset (no split folder), or invalid ground-truth files.
    """
    if sel.count < 1:
        raise ConfigError(f"--images must be >= 1, got {sel.count}")
    scenes = None if sel.scene is None else [int(sel.scene)]
    refs = select_images(Path(dataset_dir), sel.split, scenes, None, obj_ids)
    if sel.image is not None:
        picked = [r for r in refs if r.im_id == int(sel.image)]
        if not picked:
            ids = sorted({r.im_id for r in refs})
            where = f"scene {sel.scene}" if sel.scene is not None else f"split {sel.split}"
            raise ConfigError(f"image {sel.image} is not in {where} of {dataset_dir}; image ids there: "
                              f"{ids[0]}..{ids[-1]} ({len(ids)} images)")
        refs = picked[:1]
    return refs[:sel.count]


def axis_length(obj) -> float:
    """Length of the drawn model axes, metres: half the largest extent of the model's box."""
    return 0.5 * float(np.max(obj.size))


def load_captions(scene_dir: Path) -> dict[int, str] | None:
    """``{gt_id: the longest referring expression}`` from ``scene_captions.json``, or None without the file."""
    path = Path(scene_dir) / "scene_captions.json"
    if not path.is_file():
        return None
    data = bop.read_json(path)
    out = {}
    for key, inst in (data.get("instances") or {}).items() if isinstance(data, dict) else []:
        exprs = [e for e in inst.get("expressions", []) if isinstance(e, str)]
        if exprs:
            out[int(key)] = max(exprs, key=len)
    return out


def _read_mask(ref: ImageRef, gt_id: int, visible: bool) -> np.ndarray | None:
    """The instance's mask, or None where the dataset has none (real BOP test sets ship no masks)."""
    if not ref.has_masks:
        return None
    try:
        return bop.read_mask(ref.gt_dir, ref.im_id, gt_id, visible=visible)
    except DatasetError:
        return None


def draw_instance_gt(canvas: np.ndarray, K: np.ndarray, gt: bop.ImageGT, obj, colour, scale: int,
                     visib_mask: np.ndarray | None, amodal_mask: np.ndarray | None, label: str | None,
                     placed: list | None = None) -> None:
    """Draw one instance's ground truth on ``canvas`` (the camera image enlarged ``scale`` times): visible
    contour (solid, 2 px), amodal contour (dashed, 1 px), axes, 3D box (over the axes) and ``label`` above the
    top left of its visible box, moved off the label boxes in ``placed`` (appended to)."""
    if amodal_mask is not None:
        draw_mask_contour(canvas, amodal_mask, colour, scale, thickness=1, dash=4 * scale)
    if visib_mask is not None:
        draw_mask_contour(canvas, visib_mask, colour, scale, thickness=2)
    R, t = gt.T_cam_obj.R, gt.T_cam_obj.t
    draw_axes(canvas, K, R, t, axis_length(obj), scale, thickness=2)
    draw_box(canvas, box_corner_pixels(K, R, t, obj.keypoints_bbox), colour, scale, thickness=1)
    if label:
        x, y = (gt.bbox_visib if gt.bbox_visib[2] > 0 else gt.bbox_obj)[:2]
        org = to_canvas(np.array([[x, y]], dtype=np.float64) - 0.5, scale)[0]
        draw_label(canvas, label, (org[0], org[1] - 20), colour=colour, avoid=placed)


def gt_canvas(ref: ImageRef, objects, scale: int, rgb: np.ndarray | None = None,
              only: Sequence[int] | None = None, labels: bool = True) -> tuple[np.ndarray, list[int]]:
    """The image's RGB enlarged ``scale`` times with every visible instance's ground truth drawn (instance
    ``k`` in :func:`~simtest.viz.draw.palette` colour ``k``), and the gt ids drawn. ``only``: these gt ids."""
    rgb = bop.read_image(ref.scene_dir, ref.im_id) if rgb is None else rgb
    canvas = upscale(rgb, scale)
    K = ref.info["K"]
    drawn: list[int] = []
    placed: list = []
    for j, g in enumerate(ref.info["gt"]):
        if (only is not None and j not in only) or g.visib_fract <= 0:
            continue
        obj = objects.get(g.obj_id)
        label = f"[{j}] {obj.name} v={g.visib_fract:.2f}" if labels else None
        draw_instance_gt(canvas, K, g, obj, palette(j), scale, _read_mask(ref, j, True), _read_mask(ref, j, False),
                         label, placed)
        drawn.append(j)
    return canvas, drawn


def _dense_row(ref: ImageRef, scale: int, width: int) -> np.ndarray | None:
    panels = dense_panels(ref.scene_dir, ref.im_id)
    if not panels:
        return None
    n = max(4, len(panels))
    gap = 6
    pw = (width - gap * (n - 1)) // n
    tiles = []
    for name, pic in panels:
        big = upscale(pic.image, scale, nearest=True)
        ph = int(round(big.shape[0] * pw / big.shape[1]))
        small = cv2.resize(big, (pw, ph), interpolation=cv2.INTER_AREA)
        tiles.append(titled(small, name, [pic.caption]))
    return hstack(tiles, gap)


def dataset_card(ref: ImageRef, objects, scale: int | None = None, captions: dict[int, str] | None = None
                 ) -> np.ndarray:
    """One image's card (see the module docstring); ``scale`` None: :func:`~simtest.viz.sheet.upscale_factor`."""
    rgb = bop.read_image(ref.scene_dir, ref.im_id)
    s = upscale_factor(rgb.shape[1], rgb.shape[0]) if scale is None else int(scale)
    canvas, drawn = gt_canvas(ref, objects, s, rgb)
    tiles = [titled(canvas, f"RGB + ground truth ({len(drawn)} of {len(ref.info['gt'])} instances visible)")]
    if ref.has_depth:  # real test excerpts may ship RGB only
        depth = colourize_depth(bop.read_depth(ref.scene_dir, ref.im_id, ref.info["depth_scale"]))
        tiles.append(titled(upscale(depth.image, s, nearest=True), depth.caption))
    top = hstack(tiles)
    parts = [text_strip([f"scene {ref.scene_id:06d}  image {ref.im_id:06d}   {ref.scene_dir}"], top.shape[1]), top]
    dense = _dense_row(ref, s, top.shape[1])
    if dense is not None:
        parts.append(dense)
    if captions:
        parts.append(text_strip([(f"[{j}] {captions[j]}", palette(j)) for j in drawn if j in captions],
                                top.shape[1]))
    parts.append(legend_strip(DATASET_LEGEND, top.shape[1]))
    return vstack(parts, 4)
