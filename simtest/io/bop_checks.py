"""Checks of BOP scene files as read (``scene_camera.json``, ``scene_gt.json``, ``scene_gt_info.json``):
shapes, finite values, rotations, known object ids, entries per image. Vectorised per scene with numpy; Python
loops only to name the first bad entry. Every error is a :class:`~simtest.errors.DatasetError` naming the file,
image, instance, field, the bad value and what is allowed. Used by :func:`simtest.io.bop.read_scene_files`.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any
from pathlib import Path

import numpy as np

from simtest.errors import DatasetError

__all__ = ["ROT_TOL", "ROT_REPAIR_TOL", "RotationRepairs", "nearest_rotations", "GT_INFO_FIELDS",
           "validate_camera_json", "validate_scene_camera", "validate_scene_gt",
           "validate_scene_gt_info", "is_number", "short_repr"]


#: Largest entry of ``|R^T R - I|`` of a stored rotation that is read as it is (files written by simtest and
#: BlenderProc round rotations to ~1e-6).
ROT_TOL = 1e-3
#: Largest entry of ``|R^T R - I|`` of a stored rotation that is repaired (projected to the nearest rotation)
#: rather than refused: real BOP test sets are distributed with rotations rounded to ~1e-2 (LM-O: up to 0.0094).
ROT_REPAIR_TOL = 1e-2
#: Fields every ``scene_gt_info.json`` entry has (as the BOP toolkit writes them).
GT_INFO_FIELDS = ("bbox_obj", "bbox_visib", "px_count_all", "px_count_valid", "px_count_visib", "visib_fract")
_GT_FIELDS = ("obj_id", "cam_R_m2c", "cam_t_m2c")


def is_number(v: Any) -> bool:
    """A JSON number (int or float, not bool)."""
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def short_repr(v: Any, limit: int = 120) -> str:
    """``repr(v)`` cut to ``limit`` characters, for error messages."""
    text = repr(v)
    return text if len(text) <= limit else text[:limit] + "..."


def _image_ids(data: Any, path: Path, what: str) -> dict[int, Any]:
    """``{im_id: value}`` of a scene file keyed by image id; checks it is an object with integer keys."""
    if not isinstance(data, dict):
        raise DatasetError(f"{path}: expected a JSON object mapping image ids to {what}, got "
                           f"{type(data).__name__}")
    out: dict[int, Any] = {}
    for key, value in data.items():
        try:
            im = int(key)
        except ValueError:
            im = -1
        if im < 0:
            raise DatasetError(f"{path}: key {key!r} is not an image id; allowed: non-negative integers")
        out[im] = value
    return out


def _array(values: list, empty_shape: tuple[int, ...]) -> np.ndarray | None:
    """``np.array(values)`` (one C-level conversion), or None when the values are ragged."""
    if not values:
        return np.zeros(empty_shape)
    try:
        return np.array(values)
    except (ValueError, TypeError):
        return None


def _rows(values: list, n: int, field: str, path: Path, where: Callable[[int], str]) -> np.ndarray:
    """``(len(values), n)`` float64 array of lists of ``n`` finite numbers; the first bad entry is named."""
    for i, v in enumerate(values):
        if not isinstance(v, list) or len(v) != n:
            raise DatasetError(f"{path}: {where(i)}: {field} is {short_repr(v)}; allowed: a list of {n} finite numbers")
    arr = _array(values, (0, n))
    if arr is None or arr.ndim != 2 or arr.dtype.kind not in "iuf":
        i = next((i for i, v in enumerate(values) if not all(is_number(x) for x in v)), 0)
        raise DatasetError(f"{path}: {where(i)}: {field} is {short_repr(values[i])}; allowed: a list of {n} finite "
                           "numbers")
    arr = arr.astype(np.float64)
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        i = int(np.argmax(bad))
        raise DatasetError(f"{path}: {where(i)}: {field} is {short_repr(values[i])} (NaN or infinite); allowed: {n} "
                           "finite numbers")
    return arr


def _column(values: list, field: str, path: Path, where: Callable[[int], str], integer: bool = False) -> np.ndarray:
    """1-D float64 array of single finite numbers (integers if ``integer``); the first bad entry is named."""
    arr = _array(values, (0,))
    kind = "an integer" if integer else "a finite number"
    if arr is None or arr.ndim != 1 or arr.dtype.kind not in "iuf":
        i = next((i for i, v in enumerate(values) if not is_number(v)), 0)
        raise DatasetError(f"{path}: {where(i)}: {field} is {short_repr(values[i])}; allowed: {kind}")
    arr = arr.astype(np.float64)
    bad = ~np.isfinite(arr) | ((arr != np.round(arr)) if integer else False)
    if np.any(bad):
        i = int(np.argmax(bad))
        raise DatasetError(f"{path}: {where(i)}: {field} is {short_repr(values[i])}; allowed: {kind}")
    return arr


@dataclass
class RotationRepairs:
    """A tally of stored rotations that were not orthonormal within :data:`ROT_TOL` but within
    :data:`ROT_REPAIR_TOL`, and were projected to the nearest rotation as they were read.

    Attributes:
        count: Rotations repaired.
        worst: The largest ``max |R^T R - I|`` among them.
        worst_where: ``"FILE: image I, instance J"`` of the worst one.
    """

    count: int = 0
    worst: float = 0.0
    worst_where: str = ""

    def add(self, other: "RotationRepairs") -> None:
        """Add another tally to this one."""
        self.count += other.count
        if other.worst > self.worst:
            self.worst, self.worst_where = other.worst, other.worst_where

    def summary(self) -> str:
        """One line for a log or a report: how many, the worst deviation and where; ``""`` when none."""
        if not self.count:
            return ""
        return (f"{self.count} ground-truth rotation{'s' if self.count != 1 else ''} not orthonormal to "
                f"{ROT_TOL:g} (worst max |R^T R - I| = {self.worst:.3g}, {self.worst_where}) projected to the "
                f"nearest rotation (up to {ROT_REPAIR_TOL:g} is repaired, as real BOP annotations are rounded)")


def nearest_rotations(M: np.ndarray) -> np.ndarray:
    """The rotation nearest in the Frobenius norm to each (3, 3) matrix of ``M`` (N, 3, 3): ``U V^T`` of its SVD,
    with the sign of the last singular direction flipped where that product would be a reflection."""
    U, _, Vt = np.linalg.svd(M)
    R = U @ Vt
    flip = np.linalg.det(R) < 0
    if flip.any():
        U[flip, :, 2] *= -1
        R[flip] = U[flip] @ Vt[flip]
    return R


def _check_rotations(R9: np.ndarray, field: str, path: Path, where: Callable[[int], str],
                     entries: list | None = None, repairs: RotationRepairs | None = None) -> None:
    """Every row of ``R9`` (row-major 3x3) orthonormal within :data:`ROT_TOL` with determinant +1.

    With ``repairs`` (and the parsed ``entries`` whose ``field`` holds those rows), a rotation off by at most
    :data:`ROT_REPAIR_TOL` with determinant > 0 is replaced in its entry by the nearest rotation and counted in
    ``repairs``; anything further off is refused as without them.
    """
    M = R9.reshape(-1, 3, 3)
    dev = np.abs(np.einsum("nji,njk->nik", M, M) - np.eye(3)).max(axis=(1, 2))
    det = np.linalg.det(M)
    limit = ROT_TOL if repairs is None else ROT_REPAIR_TOL
    bad = (dev > limit) | (det <= 0)
    if bad.any():
        i = int(np.argmax(bad))
        raise DatasetError(
            f"{path}: {where(i)}: {field} is {short_repr(R9[i].tolist(), 200)}, not a rotation (max |R^T R - I| = "
            f"{dev[i]:.3g}, det = {det[i]:.3g}); allowed: a row-major orthonormal 3x3 matrix with det +1 "
            f"(|R^T R - I| <= {ROT_TOL:g}; up to {ROT_REPAIR_TOL:g} is repaired when reading ground truth)")
    fix = np.flatnonzero(dev > ROT_TOL)
    if repairs is None or not len(fix):
        return
    fixed = nearest_rotations(M[fix])
    for k, i in enumerate(fix):
        entries[i][field] = [float(v) for v in fixed[k].reshape(-1)]
    worst = int(fix[np.argmax(dev[fix])])
    repairs.add(RotationRepairs(len(fix), float(dev[worst]), f"{path}: {where(worst)}"))


def _check_entries(items: list, fields: tuple[str, ...], path: Path, where: Callable[[int], str]) -> None:
    """Every item is a JSON object holding ``fields``."""
    need = set(fields)
    for i, e in enumerate(items):
        if isinstance(e, dict) and e.keys() >= need:
            continue
        if not isinstance(e, dict):
            raise DatasetError(f"{path}: {where(i)}: entry is {short_repr(e)}; allowed: an object with fields "
                               f"{', '.join(fields)}")
        missing = next(f for f in fields if f not in e)
        raise DatasetError(f"{path}: {where(i)}: field {missing!r} is missing (required: {', '.join(fields)})")


def validate_scene_camera(cams: Any, path: Path, repairs: RotationRepairs | None = None) -> dict[int, dict]:
    """Check a parsed ``scene_camera.json``: ``cam_K`` 9 finite numbers with ``fx, fy > 0``; ``depth_scale``
    (if present) > 0; ``cam_R_w2c`` / ``cam_t_w2c`` (if present) a rotation and 3 finite numbers (mm).
    With ``repairs``, nearly orthonormal rotations are repaired in ``cams`` and counted (:func:`_check_rotations`).

    Returns:
        ``{im_id: entry}``.

    Raises:
        DatasetError: Naming the file, image id, field and bad value.
    """
    by_im = _image_ids(cams, path, "camera entries")
    ims = list(by_im)
    entries = list(by_im.values())
    _check_entries(entries, ("cam_K",), path, lambda i: f"image {ims[i]}")
    K = _rows([e["cam_K"] for e in entries], 9, "cam_K", path, lambda i: f"image {ims[i]}")
    bad = (K[:, 0] <= 0) | (K[:, 4] <= 0)
    if bad.any():
        i = int(np.argmax(bad))
        raise DatasetError(f"{path}: image {ims[i]}: cam_K is {K[i].tolist()} with fx = {K[i, 0]:g}, fy = "
                           f"{K[i, 4]:g}; allowed: fx > 0 and fy > 0 (row-major [fx, 0, cx, 0, fy, cy, 0, 0, 1])")
    with_ds = [i for i, e in enumerate(entries) if "depth_scale" in e]

    def at_ds(k: int) -> str:
        return f"image {ims[with_ds[k]]}"

    ds = _column([entries[i]["depth_scale"] for i in with_ds], "depth_scale", path, at_ds)
    if (ds <= 0).any():
        k = int(np.argmax(ds <= 0))
        raise DatasetError(f"{path}: {at_ds(k)}: depth_scale is {ds[k]:g}; allowed: a number > 0 (millimetres "
                           "per depth unit)")
    with_pose = [i for i, e in enumerate(entries) if "cam_R_w2c" in e or "cam_t_w2c" in e]

    def at_pose(k: int) -> str:
        return f"image {ims[with_pose[k]]}"

    posed = [entries[i] for i in with_pose]
    _check_entries(posed, ("cam_R_w2c", "cam_t_w2c"), path, at_pose)
    R = _rows([e["cam_R_w2c"] for e in posed], 9, "cam_R_w2c", path, at_pose)
    _check_rotations(R, "cam_R_w2c", path, at_pose, posed, repairs)
    _rows([e["cam_t_w2c"] for e in posed], 3, "cam_t_w2c", path, at_pose)
    return by_im


def validate_scene_gt(gts: Any, path: Path, obj_ids: Iterable[int] | None = None,
                      repairs: RotationRepairs | None = None) -> dict[int, list]:
    """Check a parsed ``scene_gt.json``: per image a list of ``{obj_id, cam_R_m2c, cam_t_m2c}``; ``obj_id`` an
    integer (one of ``obj_ids`` if given), ``cam_R_m2c`` a rotation (9 numbers, orthonormal within
    :data:`ROT_TOL`, det +1), ``cam_t_m2c`` 3 finite numbers (mm). Vectorised over the scene. With ``repairs``,
    rotations orthonormal within :data:`ROT_REPAIR_TOL` are projected to the nearest rotation in ``gts`` and
    counted there.

    Returns:
        ``{im_id: [entry, ...]}``.

    Raises:
        DatasetError: Naming the file, image id, instance index, field and bad value.
    """
    by_im = _image_ids(gts, path, "ground truth")
    locs: list[tuple[int, int]] = []
    flat: list = []
    for im, insts in by_im.items():
        if not isinstance(insts, list):
            raise DatasetError(f"{path}: image {im}: value is {short_repr(insts)}; allowed: a list of instances")
        locs.extend((im, j) for j in range(len(insts)))
        flat.extend(insts)

    def where(i: int) -> str:
        return f"image {locs[i][0]}, instance {locs[i][1]}"

    _check_entries(flat, _GT_FIELDS, path, where)
    R = _rows([g["cam_R_m2c"] for g in flat], 9, "cam_R_m2c", path, where)
    _check_rotations(R, "cam_R_m2c", path, where, flat, repairs)
    _rows([g["cam_t_m2c"] for g in flat], 3, "cam_t_m2c", path, where)
    ids = _column([g["obj_id"] for g in flat], "obj_id", path, where, integer=True)
    if obj_ids is not None:
        known = sorted({int(o) for o in obj_ids})
        bad = ~np.isin(ids, known)
        if bad.any():
            i = int(np.argmax(bad))
            raise DatasetError(f"{path}: {where(i)}: obj_id {int(ids[i])} is not a dataset object; known obj_ids "
                               f"(models/models_info.json or the manifest's object set): {known}")
    return by_im


def validate_scene_gt_info(infos: Any, gts: dict[int, list], path: Path) -> dict[int, list]:
    """Check a parsed ``scene_gt_info.json`` against the validated ``scene_gt`` (``{im_id: [entry]}``): the
    same images with the same number of instances, every entry with :data:`GT_INFO_FIELDS`, boxes 4 finite
    numbers, pixel counts non-negative integers, ``visib_fract`` in [0, 1].

    Returns:
        ``{im_id: [entry, ...]}``.
    """
    by_im = _image_ids(infos, path, "ground-truth info")
    missing = sorted(set(gts) - set(by_im))
    if missing:
        raise DatasetError(f"{path}: no entry for image ids {short_repr(missing)} that scene_gt.json annotates")
    locs: list[tuple[int, int]] = []
    flat: list = []
    for im, insts in gts.items():
        info = by_im[im]
        if not isinstance(info, list) or len(info) != len(insts):
            got = f"{len(info)} entries" if isinstance(info, list) else f"value {short_repr(info)}"
            raise DatasetError(f"{path}: image {im}: {got} but scene_gt.json has {len(insts)} instances; "
                               "allowed: a list with one entry per scene_gt.json instance, in the same order")
        locs.extend((im, j) for j in range(len(info)))
        flat.extend(info)

    def where(i: int) -> str:
        return f"image {locs[i][0]}, instance {locs[i][1]}"

    _check_entries(flat, GT_INFO_FIELDS, path, where)
    for field in ("bbox_obj", "bbox_visib"):
        _rows([e[field] for e in flat], 4, field, path, where)
    for field in ("px_count_all", "px_count_valid", "px_count_visib"):
        v = _column([e[field] for e in flat], field, path, where, integer=True)
        if (v < 0).any():
            i = int(np.argmax(v < 0))
            raise DatasetError(f"{path}: {where(i)}: {field} is {int(v[i])}; allowed: an integer >= 0")
    v = _column([e["visib_fract"] for e in flat], "visib_fract", path, where)
    bad = (v < 0) | (v > 1)
    if bad.any():
        i = int(np.argmax(bad))
        raise DatasetError(f"{path}: {where(i)}: visib_fract is {short_repr(flat[i]['visib_fract'])}; allowed: a number "
                           "in [0, 1]")
    return by_im


def validate_camera_json(data: dict, path: Path) -> None:
    """Check the values of a dataset's ``camera.json`` (pixels; ``depth_scale`` in mm per unit).

    Raises:
        DatasetError: A value that is not finite, a non-positive focal length or depth scale, or a size that is
            not a positive integer.
    """
    for key in ("fx", "fy", "cx", "cy", "width", "height", "depth_scale"):
        if key not in data:
            continue
        v = data[key]
        ok = is_number(v) and math.isfinite(v)
        if key in ("width", "height"):
            ok = ok and float(v).is_integer() and v >= 1
            allowed = "a positive integer (pixels)"
        elif key in ("fx", "fy", "depth_scale"):
            ok = ok and v > 0
            allowed = "a finite number > 0"
        else:
            allowed = "a finite number"
        if not ok:
            raise DatasetError(f"{path}: field {key!r} is {v!r}; allowed: {allowed}")
