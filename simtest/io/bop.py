"""BOP dataset reader and writer (scenewise layout, as the BOP toolkit reads it).

This module (with :mod:`simtest.io.bop_models` for ``models/``) is the only place that knows millimetres and
``depth_scale``: everything it returns or accepts is in metres, and it converts at the file boundary.

Layout written::

    DATASET/camera.json, models/, manifest.json
    DATASET/{split}/{scene:06d}/rgb/{im:06d}.jpg|png, depth/{im:06d}.png (uint16, mm = value * depth_scale),
        mask/{im:06d}_{gt:06d}.png, mask_visib/..., scene_camera.json, scene_gt.json, scene_gt_info.json,
        scene_gt_coco.json (optional)
"""

from __future__ import annotations

import json
import logging
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import cv2
import numpy as np

from simtest.camera import CameraModel
from simtest.errors import ConfigError, DatasetError
from simtest.geometry import Pose
from simtest.io.bop_splits import dataset_split_dir, resolve_split, scene_dirs, split_names
from simtest.io.bop_checks import (GT_INFO_FIELDS, ROT_TOL, RotationRepairs, short_repr, validate_camera_json,
                                   validate_scene_camera, validate_scene_gt, validate_scene_gt_info)
from simtest.io.coco import coco_annotation, coco_scene
from simtest.io.dense import write_png16
from simtest.io.files import (atomic_write_json, atomic_write_text, dump_json_keyed,
                              write_new_file)
from simtest.io.png import encode_depth_png, encode_mask_png
from simtest.io.scene_folder import SceneFolder

__all__ = ["MM_PER_M", "ImageGT", "encode_image", "read_json", "SceneWriter", "write_camera_json",
    "read_camera_json", "encode_depth", "decode_depth", "rgb_to_bgr", "read_scene", "read_image", "read_depth",
    "read_mask", "scene_dirs", "pose_to_bop", "pose_from_bop", "dataset_split_dir", "split_names", "resolve_split",
    "SceneFiles", "read_scene_files", "validate_scene_camera", "validate_scene_gt", "validate_scene_gt_info",
    "ROT_TOL", "RotationRepairs", "GT_INFO_FIELDS", "mask_bbox", "RGB_FORMATS", "COCO_BBOX_TYPES"]

#: Names that moved to :mod:`simtest.io.scene_folder` (the atomic scene folder); they forward there.
MOVED = ("withhold_labels", "UNLABELLED_KEEP")


def __getattr__(name: str) -> Any:
    """The moved names (:data:`MOVED`), from :mod:`simtest.io.scene_folder`, with a DeprecationWarning."""
    if name in MOVED:
        import warnings

        from simtest.io import scene_folder

        warnings.warn(f"simtest.io.bop.{name} moved to simtest.io.scene_folder.{name}", DeprecationWarning,
                      stacklevel=2)
        return getattr(scene_folder, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

log = logging.getLogger(__name__)

#: The only metres <-> millimetres factor in simtest.
MM_PER_M = 1000.0
#: Largest representable depth value of a uint16 PNG.
_UINT16_MAX = 65535
#: File formats of ``rgb/`` images the writer knows (BOP's PBR layout stores JPEG).
RGB_FORMATS: tuple[str, ...] = ("jpg", "png")
#: Boxes of ``scene_gt_coco.json`` (as the BOP toolkit's ``calc_gt_coco.py``): of the whole object in the image
#: (``amodal``, the toolkit's default) or of its visible part (``modal``).
COCO_BBOX_TYPES: tuple[str, ...] = ("amodal", "modal")


def mask_bbox(mask: np.ndarray, x0: int = 0, y0: int = 0) -> list[int]:
    """BOP box ``[x, y, w, h]`` (pixels) of a mask, as the BOP toolkit's ``misc.calc_2d_bbox``.

    ``x, y`` are the smallest column and row that hold a mask pixel, ``w = xmax - xmin`` and ``h = ymax - ymin``
    (no +1: a one-pixel mask has ``w = h = 0``); ``[-1, -1, -1, -1]`` when the mask is empty.

    Args:
        mask: (H, W) mask (non-zero = inside).
        x0, y0: Pixel coordinates of ``mask[0, 0]`` (for a mask cut from a larger canvas).
    """
    m = np.asarray(mask).astype(bool, copy=False)
    ys = np.flatnonzero(m.any(axis=1))
    if len(ys) == 0:
        return [-1, -1, -1, -1]
    xs = np.flatnonzero(m.any(axis=0))
    return [int(xs[0] + x0), int(ys[0] + y0), int(xs[-1] - xs[0]), int(ys[-1] - ys[0])]


def pose_to_bop(T: Pose) -> tuple[list[float], list[float]]:
    """(cam_R_m2c as 9 row-major floats, cam_t_m2c in mm) from a pose in metres."""
    return [float(v) for v in T.R.reshape(-1)], [float(v) for v in T.t * MM_PER_M]


def pose_from_bop(R9, t3_mm) -> Pose:
    """A pose in metres from BOP's flat rotation and millimetre translation."""
    return Pose(np.asarray(R9, dtype=np.float64).reshape(3, 3), np.asarray(t3_mm, dtype=np.float64) / MM_PER_M)


def encode_depth(depth_m: np.ndarray, depth_scale: float) -> np.ndarray:
    """Planar depth in metres -> uint16 BOP depth (``mm = value * depth_scale``).

    Missing depth (0) stays 0; depth beyond the largest representable value becomes 0 (missing) rather than
    wrapping or clipping to a wrong distance.
    """
    v = np.asarray(depth_m, dtype=np.float64) * (MM_PER_M / depth_scale)
    np.rint(v, out=v)  # np.round's rounding (half to even), in place
    v[~((v >= 0) & (v <= _UINT16_MAX))] = 0  # NaN fails both comparisons
    return v.astype(np.uint16)


def decode_depth(value: np.ndarray, depth_scale: float) -> np.ndarray:
    """uint16 BOP depth -> float32 metres (0 = missing)."""
    return (value.astype(np.float64) * (depth_scale / MM_PER_M)).astype(np.float32)


def _png(img: np.ndarray, mask: bool = False) -> bytes:
    """Fast lossless PNG: zlib level 1 with the cheapest filter that still compresses well.

    Masks (``mask``: non-zero = inside, written as 0/255): :func:`simtest.io.png.encode_mask_png` (no filter,
    run-length strategy, through zlib-ng); one-channel 16-bit images (depth):
    :func:`simtest.io.png.encode_depth_png` (SUB filter, zlib-ng level 2); colour: OpenCV with the SUB filter
    (faster than adaptive filtering, as small or smaller here).
    """
    if mask:
        return encode_mask_png(img)
    if img.ndim == 2 and img.dtype == np.uint16:  # depth (and one-channel 16-bit channels)
        return encode_depth_png(img)
    params = [cv2.IMWRITE_PNG_COMPRESSION, 1, cv2.IMWRITE_PNG_FILTER, cv2.IMWRITE_PNG_FILTER_SUB]
    ok, buf = cv2.imencode(".png", img, params)
    if not ok:  # pragma: no cover
        raise DatasetError("PNG encoding failed")
    return buf.tobytes()


def encode_image(img: np.ndarray, suffix: str = ".png", mask: bool = False, jpg_quality: int = 95) -> bytes:
    """Encode a BGR, grey or 16-bit image as ``.png`` (see :func:`_png`; ``mask``: a mask, non-zero = inside,
    written as 0/255) or ``.jpg`` (``jpg_quality``)."""
    if suffix.lower() in (".jpg", ".jpeg"):
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, int(jpg_quality)])
        if not ok:  # pragma: no cover
            raise DatasetError("JPEG encoding failed")
        return buf.tobytes()
    if suffix.lower() != ".png":
        raise DatasetError(f"cannot write images as {suffix!r}; use .png or .jpg")
    return _png(img, mask)


def _write_rgb_file(path: Path, rgb: np.ndarray, jpg_quality: int) -> None:
    """Encode an RGB-order image as ``path``'s format (:func:`encode_image`) into the scene's private folder."""
    write_new_file(path, encode_image(rgb_to_bgr(rgb), path.suffix, jpg_quality=jpg_quality))


def _write_depth_file(path: Path, depth_m: np.ndarray, depth_scale: float) -> None:
    """Write planar depth (metres) as a BOP uint16 depth PNG (:func:`encode_depth`,
    :func:`simtest.io.png.encode_depth_png`) into the scene's private folder."""
    write_new_file(path, encode_depth_png(encode_depth(depth_m, depth_scale)))


def rgb_to_bgr(rgb: np.ndarray) -> np.ndarray:
    """An (H, W, 3) uint8 image with its channels reversed (OpenCV's order), as a new contiguous array."""
    return cv2.cvtColor(np.asarray(rgb), cv2.COLOR_RGB2BGR)


def _write_mask_files(paths: list[Path], masks: list[np.ndarray]) -> None:
    """Write masks (non-zero = inside) as 0/255 8-bit PNGs into the scene's private folder."""
    for path, mask in zip(paths, masks):
        write_new_file(path, encode_mask_png(mask))


def write_camera_json(path: str | Path, camera: CameraModel, depth_scale: float) -> None:
    K = camera.K
    atomic_write_json(path, {"cx": float(K[0, 2]), "cy": float(K[1, 2]), "depth_scale": float(depth_scale),
                             "fx": float(K[0, 0]), "fy": float(K[1, 1]), "height": camera.height,
                             "width": camera.width})


@dataclass(frozen=True)
class ImageGT:
    """Ground truth of one object instance in one image, as written to / read from the BOP files."""

    obj_id: int
    T_cam_obj: Pose
    bbox_obj: list[int]
    bbox_visib: list[int]
    px_count_all: int
    px_count_valid: int
    px_count_visib: int
    visib_fract: float


class SceneWriter:
    """Writes one BOP scene folder; frames are added one by one, the JSON files at :meth:`close`. It alone
    writes into the folder: images and their encodings, the scene's records (:meth:`write_json`).

    The scene is assembled in a hidden sibling folder of its own (``.{scene:06d}.<random>.partial``,
    :class:`~simtest.io.scene_folder.SceneFolder`) and renamed into place when complete, so a scene folder
    either exists whole or not at all (a killed run leaves only partial folders, which a resumed run deletes),
    and two writers of one scene never mix their files.
    """

    #: Name prefix of the writer threads (benchmarks group CPU time by it).
    THREAD_NAME = "bop-writer"

    def __init__(self, split_dir: str | Path, scene_id: int, depth_scale: float = 0.1,
                 rgb_format: str = "jpg", jpg_quality: int = 95, coco: bool = False, coco_bbox: str = "amodal",
                 coco_categories: list[int] | None = None, threads: int = 2) -> None:
        """Start the scene in its hidden partial folder.

        Args:
            split_dir: The split folder (``DATASET/train_pbr``).
            scene_id: Scene id (the folder name, 6 digits).
            depth_scale: Millimetres per depth PNG unit.
            rgb_format: ``"jpg"`` (BOP's PBR layout; lossy at ``jpg_quality``) or ``"png"`` (lossless).
            jpg_quality: JPEG quality 1-100.
            coco: Also write ``scene_gt_coco.json``.
            coco_bbox: Box of each COCO annotation: ``"amodal"`` (whole object in the image) or ``"modal"``.
            coco_categories: Object ids listed as COCO categories (the whole object set, as the BOP toolkit
                does) besides those that appear in the scene.
            threads: Threads that encode and write the images while the caller renders the next one (>= 1).
        """
        if rgb_format not in RGB_FORMATS:
            raise ConfigError(f"rgb_format = {rgb_format!r} is invalid; allowed: {', '.join(RGB_FORMATS)}")
        if coco_bbox not in COCO_BBOX_TYPES:
            raise ConfigError(f"coco_bbox = {coco_bbox!r} is invalid; allowed: {', '.join(COCO_BBOX_TYPES)}")
        if not 1 <= int(jpg_quality) <= 100:
            raise ConfigError(f"jpg_quality = {jpg_quality!r} is invalid; allowed: [1, 100]")
        self.folder = SceneFolder(split_dir, f"{scene_id:06d}")
        self.final_dir, self.dir = self.folder.final, self.folder.dir
        for sub in ("rgb", "depth", "mask", "mask_visib"):
            (self.dir / sub).mkdir()
        self.scene_id = scene_id
        self.depth_scale = float(depth_scale)
        self.rgb_format = rgb_format
        self.jpg_quality = int(jpg_quality)
        self.coco = coco
        self.coco_bbox = coco_bbox
        self.coco_categories = None if coco_categories is None else sorted(int(c) for c in coco_categories)
        self.scene_camera: dict[str, dict] = {}
        self.scene_gt: dict[str, list] = {}
        self.scene_gt_info: dict[str, list] = {}
        self.coco_images: list[dict] = []
        self.coco_annotations: list[dict] = []
        self.scene_keypoints: dict[str, list] = {}
        #: ``{obj_id: (bbox corners, surface keypoints)}`` named in the COCO categories (keypoints channel).
        self.keypoint_counts: dict[int, tuple[int, int]] | None = None
        # Image encoding (cv2 releases the GIL) and file writes run beside the next frame's rendering.
        from concurrent.futures import ThreadPoolExecutor

        self._pool = ThreadPoolExecutor(max_workers=max(1, int(threads)), thread_name_prefix=self.THREAD_NAME)
        self._pending: list = []

    def _submit(self, fn, *args) -> None:
        """Queue ``fn(*args)`` on the writer threads; the arrays in ``args`` must not change afterwards."""
        self._pending.append(self._pool.submit(fn, *args))

    def _write_rgb(self, im_id: int, rgb: np.ndarray) -> None:
        """Queue ``rgb/{im_id:06d}.jpg|png`` (``rgb`` in RGB order)."""
        path = self.dir / "rgb" / f"{im_id:06d}.{self.rgb_format}"
        self._submit(_write_rgb_file, path, rgb, self.jpg_quality)

    def _drain(self, keep: int = 0) -> None:
        """Wait for queued writes (all, or all but the newest ``keep``), re-raising their errors."""
        while len(self._pending) > keep:
            self._pending.pop(0).result()

    def add(self, im_id: int, rgb: np.ndarray, depth_m: np.ndarray, camera: CameraModel,
            instances: list, masks: list[np.ndarray], masks_visib: list[np.ndarray],
            images: dict[str, np.ndarray] | None = None, keypoints: list[np.ndarray] | None = None) -> None:
        """Write one image.

        Args:
            im_id: Image id within the scene.
            rgb: (H, W, 3) uint8, RGB order.
            depth_m: (H, W) planar depth, metres, 0 = missing.
            camera: Camera of this image (K and ``T_world_cam``).
            instances: Per-instance objects with the :class:`ImageGT` fields.
            masks, masks_visib: (H, W) bool amodal / visible masks, same order as ``instances``.
            images: Encoded dense channels ``{folder: uint16 image}`` (:mod:`simtest.io.dense`).
            keypoints: Per instance (J, 3) ``[u, v, visibility]`` (``scene_keypoints.json``, COCO keypoints).

        The images are encoded and written by writer threads while the caller goes on: ``rgb``, ``depth_m`` and
        the masks must not be modified afterwards (:meth:`close` waits for every write).
        """
        key = str(im_id)
        self._drain(keep=16)  # bound the memory held by queued images (four tasks per image)
        self._write_rgb(im_id, rgb)
        self._submit(_write_depth_file, self.dir / "depth" / f"{im_id:06d}.png", depth_m, self.depth_scale)
        T_cam_world = camera.T_cam_world
        R9, t_mm = pose_to_bop(T_cam_world)
        self.scene_camera[key] = {"cam_K": [float(v) for v in camera.K.reshape(-1)], "depth_scale": self.depth_scale,
                                  "cam_R_w2c": R9, "cam_t_w2c": t_mm}
        gts, infos = [], []
        names = [f"{im_id:06d}_{gt_id:06d}.png" for gt_id in range(len(instances))]
        # One task per mask folder and image: the writer threads share out fewer, larger pieces of work.
        self._submit(_write_mask_files, [self.dir / "mask" / n for n in names], list(masks))
        self._submit(_write_mask_files, [self.dir / "mask_visib" / n for n in names], list(masks_visib))
        for k, (inst, m, mv) in enumerate(zip(instances, masks, masks_visib)):
            R9, t_mm = pose_to_bop(inst.T_cam_obj)
            gts.append({"cam_R_m2c": R9, "cam_t_m2c": t_mm, "obj_id": int(inst.obj_id)})
            infos.append({"bbox_obj": list(inst.bbox_obj), "bbox_visib": list(inst.bbox_visib),
                          "px_count_all": int(inst.px_count_all), "px_count_valid": int(inst.px_count_valid),
                          "px_count_visib": int(inst.px_count_visib), "visib_fract": float(inst.visib_fract)})
            if self.coco and mv.any():
                self.coco_annotations.append(coco_annotation(
                    len(self.coco_annotations) + 1, im_id, inst, m, mv, self.coco_bbox,
                    None if keypoints is None else keypoints[k]))
        self.scene_gt[key] = gts
        self.scene_gt_info[key] = infos
        for folder, image in (images or {}).items():
            self.add_image(folder, im_id, image)
        if keypoints is not None:
            self.scene_keypoints[key] = [{"obj_id": int(i.obj_id), "keypoints": np.round(k, 4).tolist()}
                                         for i, k in zip(instances, keypoints)]
        if self.coco:
            self.coco_images.append({"id": im_id, "file_name": f"rgb/{im_id:06d}.{self.rgb_format}",
                                     "width": camera.width, "height": camera.height})

    def add_image(self, folder: str, im_id: int, image: np.ndarray) -> None:
        """Write a 16-bit channel image ``folder/{im_id:06d}.png`` (a view's flow is written one view later)."""
        path = self.folder.path(f"{folder}/{im_id:06d}.png")
        path.parent.mkdir(exist_ok=True)
        self._submit(lambda p, a: write_new_file(p, write_png16(p, a)), path, image)

    def add_depth(self, folder: str, im_id: int, depth_m: np.ndarray) -> None:
        """Write a depth image ``folder/{im_id:06d}.png`` (metres, 0 = missing) in this scene's depth encoding
        (``depth_exact/`` beside a depth sensor's ``depth/``)."""
        self.add_image(folder, im_id, encode_depth(depth_m, self.depth_scale))

    def write_json(self, name: str, data: Any, *, keyed: bool = False) -> Path:
        """Write a scene record (``scene_info.json``, ``scene_occlusion.json``, captions) into the scene folder
        atomically (``keyed``: one top-level key per line); names outside the folder are refused
        (:meth:`SceneFolder.path <simtest.io.scene_folder.SceneFolder.path>`)."""
        return self.folder.write_json(name, data, keyed=keyed)

    def discard(self) -> None:
        """Drop the unfinished scene: wait for the writes in flight (their errors ignored) and delete its partial
        folder; the scene's final folder is never touched."""
        self._pool.shutdown(wait=True, cancel_futures=True)
        self.folder.discard()

    def close(self, labels_dir: str | Path | None = None) -> Path:
        """Write the scene JSON files and move the finished scene into place; returns its folder.

        Args:
            labels_dir: Withhold the labels: everything but ``rgb/``, ``depth/`` and ``scene_camera.json``
                (ground truth, masks, scene records) moves to this folder, with a copy of
                ``scene_camera.json``. It is put in place (atomically) before the scene, so a complete scene
                folder always has its labels.
        """
        self._drain()
        self._pool.shutdown()
        atomic_write_text(self.dir / "scene_camera.json", dump_json_keyed(self.scene_camera))
        atomic_write_text(self.dir / "scene_gt.json", dump_json_keyed(self.scene_gt))
        atomic_write_text(self.dir / "scene_gt_info.json", dump_json_keyed(self.scene_gt_info))
        if self.coco:
            cats = sorted(set(self.coco_categories or ()) | {a["category_id"] for a in self.coco_annotations})
            atomic_write_json(self.dir / "scene_gt_coco.json", coco_scene(
                self.scene_id, self.coco_images, self.coco_annotations, cats, self.keypoint_counts), indent=None)
        if self.scene_keypoints:
            atomic_write_text(self.dir / "scene_keypoints.json", dump_json_keyed(self.scene_keypoints))
        return self.folder.commit(labels_dir)


# ---------------------------------------------------------------------------------------------------------
# Reading
def read_json(path: str | Path) -> Any:
    """Parse a dataset JSON file; :class:`DatasetError` naming the file (and line and column) if it is
    missing, unreadable or malformed."""
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: file is missing")
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise DatasetError(f"{path}: not valid JSON at line {exc.lineno}, column {exc.colno}: {exc.msg}") from None
    except (OSError, UnicodeDecodeError) as exc:
        raise DatasetError(f"{path}: cannot read ({exc})") from None


def read_camera_json(path: str | Path) -> dict:
    """The dataset's ``camera.json``: ``fx, fy > 0``, ``cx, cy`` finite, ``width, height`` positive integers,
    ``depth_scale > 0`` if present (pixels; depth_scale in mm per depth unit)."""
    path = Path(path)
    data = read_json(path)
    if not isinstance(data, dict):
        raise DatasetError(f"{path}: expected a JSON object with fx, fy, cx, cy, width, height")
    for key in ("fx", "fy", "cx", "cy", "width", "height"):
        if key not in data:
            raise DatasetError(f"{path}: field {key!r} is missing")
    validate_camera_json(data, Path(path))
    return data


@dataclass(frozen=True)
class SceneFiles:
    """The parsed and validated JSON files of one scene folder, as stored (keys are the files' image-id
    strings, poses in millimetres). ``gt`` and ``gt_info`` are None only when read with ``require_gt=False``
    and the files are absent. ``repairs`` counts the nearly orthonormal rotations that were projected to the
    nearest rotation as they were read (:class:`~simtest.io.bop_checks.RotationRepairs`)."""

    dir: Path
    camera: dict[str, dict]
    gt: dict[str, list] | None
    gt_info: dict[str, list] | None
    repairs: RotationRepairs = field(default_factory=RotationRepairs)


def read_scene_camera(scene_dir: str | Path) -> dict[str, dict]:
    """The validated ``scene_camera.json`` of a scene, as stored (keys: image-id strings); no label file is
    read (:func:`validate_scene_camera`)."""
    cam_path = Path(scene_dir) / "scene_camera.json"
    cams = read_json(cam_path)
    validate_scene_camera(cams, cam_path)
    return cams


def read_scene_files(scene_dir: str | Path, obj_ids: Iterable[int] | None = None,
                     require_gt: bool = True) -> SceneFiles:
    """Read and validate ``scene_camera.json``, ``scene_gt.json`` and ``scene_gt_info.json`` of a scene.

    Every consumer of a dataset's ground truth reads it through here (see :func:`validate_scene_camera`,
    :func:`validate_scene_gt`, :func:`validate_scene_gt_info`); every image annotated in ``scene_gt.json``
    must have a ``scene_camera.json`` entry. Rotations off orthonormal by more than
    :data:`~simtest.io.bop_checks.ROT_TOL` but at most :data:`~simtest.io.bop_checks.ROT_REPAIR_TOL` (real BOP
    annotations are rounded) are projected to the nearest rotation and counted in ``repairs``; worse ones are
    refused.

    Args:
        scene_dir: ``DATASET/<split>/<6-digit scene>``.
        obj_ids: The dataset's object ids; a ground-truth ``obj_id`` outside them is an error. None: not checked.
        require_gt: False: a scene without ``scene_gt.json`` (a split without ground truth) is accepted;
            a ``scene_gt.json`` still needs its ``scene_gt_info.json``.

    Raises:
        DatasetError: A missing or malformed file, naming the file, image id, instance, field and value.
    """
    scene_dir = Path(scene_dir)
    cam_path, gt_path, info_path = (scene_dir / n for n in ("scene_camera.json", "scene_gt.json",
                                                            "scene_gt_info.json"))
    cams = read_json(cam_path)
    repairs = RotationRepairs()
    cam_ims = validate_scene_camera(cams, cam_path, repairs)
    if not require_gt and not gt_path.is_file():
        return SceneFiles(scene_dir, cams, None, read_json(info_path) if info_path.is_file() else None, repairs)
    gts = read_json(gt_path)
    gt_ims = validate_scene_gt(gts, gt_path, obj_ids, repairs)
    no_cam = sorted(set(gt_ims) - set(cam_ims))
    if no_cam:
        raise DatasetError(f"{gt_path}: image ids {short_repr(no_cam)} have no entry in {cam_path.name}; every "
                           "annotated image needs its camera")
    infos = read_json(info_path)
    validate_scene_gt_info(infos, gt_ims, info_path)
    return SceneFiles(scene_dir, cams, gts, infos, repairs)


def read_scene(scene_dir: str | Path, obj_ids: Iterable[int] | None = None,
               repairs: RotationRepairs | None = None) -> dict[int, dict]:
    """All annotations of one scene, in metres, validated by :func:`read_scene_files`.

    Args:
        scene_dir: ``DATASET/<split>/<6-digit scene>``.
        obj_ids: The dataset's object ids (an unknown ground-truth ``obj_id`` is an error); None: not checked.
        repairs: Add the scene's repaired rotations to this tally (the caller reports them); None: a warning
            is logged here when there are any.

    Returns:
        ``{im_id: {"K": 3x3, "depth_scale": float, "T_cam_world": Pose | None, "gt": [ImageGT, ...]}}`` for
        every image of ``scene_camera.json``.
    """
    files = read_scene_files(scene_dir, obj_ids)
    if repairs is not None:
        repairs.add(files.repairs)
    elif files.repairs.count:
        log.warning("%s", files.repairs.summary())
    gts = {int(k): v for k, v in files.gt.items()}
    infos = {int(k): v for k, v in files.gt_info.items()}
    out: dict[int, dict] = {}
    for key, cam in files.camera.items():
        im = int(key)
        T_cw = pose_from_bop(cam["cam_R_w2c"], cam["cam_t_w2c"]) if "cam_R_w2c" in cam else None
        items = [ImageGT(
            obj_id=int(g["obj_id"]), T_cam_obj=pose_from_bop(g["cam_R_m2c"], g["cam_t_m2c"]),
            bbox_obj=list(info["bbox_obj"]), bbox_visib=list(info["bbox_visib"]),
            px_count_all=int(info["px_count_all"]), px_count_valid=int(info["px_count_valid"]),
            px_count_visib=int(info["px_count_visib"]), visib_fract=float(info["visib_fract"]))
            for g, info in zip(gts.get(im, []), infos.get(im, []))]
        out[im] = {"K": np.asarray(cam["cam_K"], dtype=np.float64).reshape(3, 3),
                   "depth_scale": float(cam.get("depth_scale", 1.0)), "T_cam_world": T_cw, "gt": items}
    return out


def _image_path(scene_dir: Path, sub: str, name: str) -> Path:
    for ext in (".png", ".jpg", ".tif"):
        p = scene_dir / sub / f"{name}{ext}"
        if p.exists():
            return p
    raise DatasetError(f"{scene_dir / sub}: no image {name}.png/.jpg")


def read_image(scene_dir: str | Path, im_id: int) -> np.ndarray:
    """RGB image (H, W, 3) uint8."""
    p = _image_path(Path(scene_dir), "rgb", f"{im_id:06d}")
    img = cv2.imread(str(p), cv2.IMREAD_COLOR)
    if img is None:
        raise DatasetError(f"{p}: unreadable image")
    return img[..., ::-1].copy()


def read_depth(scene_dir: str | Path, im_id: int, depth_scale: float) -> np.ndarray:
    """Depth (H, W) float32 in metres, 0 = missing."""
    p = _image_path(Path(scene_dir), "depth", f"{im_id:06d}")
    raw = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    if raw is None or raw.dtype != np.uint16:
        raise DatasetError(f"{p}: expected a 16-bit depth PNG")
    return decode_depth(raw, depth_scale)


def read_mask(scene_dir: str | Path, im_id: int, gt_id: int, visible: bool = True) -> np.ndarray:
    """Visible (``mask_visib``) or amodal (``mask``) mask as bool (H, W)."""
    p = Path(scene_dir) / ("mask_visib" if visible else "mask") / f"{im_id:06d}_{gt_id:06d}.png"
    m = cv2.imread(str(p), cv2.IMREAD_UNCHANGED)
    if m is None:
        raise DatasetError(f"{p}: mask is missing or unreadable")
    return m > 127
