"""Checkpoint files of the learned estimators (keypoint and segmentation networks) and the object-set record
they carry (torch imported only to write or read a file).

A checkpoint is a ``dict`` of tensors and plain Python types only, so ``torch.load(path, weights_only=True)``
reads it::

    {"format": "simtest-keypoints/1" | "simtest-keypoints/2" | "simtest-segmentation/1",
     "net": network config dict, "objects": object record (below), "model": state_dict,
     "epoch": int (last finished, 0-based), "optimizer": state_dict | None, "history": [per-epoch dicts],
     "train": training settings, ...}

The object record (:func:`object_record`) names the object set the network was trained for: ``obj_ids``
(class order), ``names``, ``mesh_hashes``, ``num_vertices``, ``bbox_corners`` and ``diameters`` (metres),
``symmetric``, ``keypoint_type`` and ``keypoints`` (per object, J x 3 model-frame points in metres).
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from simtest.errors import ConfigError

__all__ = ["object_record", "check_objects", "save_checkpoint", "load_checkpoint", "model_keypoints",
           "GEOMETRY_TOL_M", "KINDS"]

#: Tolerance (metres) for treating two meshes with different hashes as the same geometry: a mesh written to a
#: float32 file and read back hashes differently, so equal vertex counts and bbox corners within this distance
#: also count as the same object.
GEOMETRY_TOL_M = 1e-5
#: How an error names the checkpoint kind of a format (others: the format's name without ``simtest-``).
KINDS = {"simtest-keypoints/1": "keypoint-estimator"}


def model_keypoints(obj: Any, keypoint_type: str) -> np.ndarray:
    """The model-frame keypoints (J, 3), metres, of ``obj`` for ``keypoint_type`` (``bbox`` or ``fps``)."""
    if keypoint_type == "bbox":
        return np.asarray(obj.keypoints_bbox, np.float64)
    if keypoint_type == "fps":
        return np.asarray(obj.keypoints_fps, np.float64)
    raise ConfigError(f"unknown keypoint type {keypoint_type!r}; valid: bbox, fps")


def object_record(objects: Any, keypoint_type: str = "bbox") -> dict[str, Any]:
    """Plain-type description of an object set (class order = sorted ids); see the module doc."""
    objs = sorted(objects, key=lambda o: int(o.obj_id))
    return {"obj_ids": [int(o.obj_id) for o in objs], "names": [str(o.name) for o in objs],
            "mesh_hashes": [str(o.mesh_hash) for o in objs], "num_vertices": [int(len(o.vertices)) for o in objs],
            "bbox_corners": [np.asarray(o.keypoints_bbox, np.float64).tolist() for o in objs],
            "diameters": [float(o.diameter) for o in objs], "symmetric": [bool(o.is_symmetric) for o in objs],
            "keypoint_type": keypoint_type,
            "keypoints": [model_keypoints(o, keypoint_type).tolist() for o in objs]}


def _describe(rec: dict[str, Any]) -> str:
    return ", ".join(f"{i} {n} (mesh {h[:10]})" for i, n, h in zip(rec["obj_ids"], rec["names"], rec["mesh_hashes"]))


def check_objects(trained: dict[str, Any], objects: Any, where: str = "checkpoint",
                  hint: str = "Train a model for this object set (simtest train keypoints --data DATASET) or "
                              "evaluate on a dataset of the trained objects") -> None:
    """Raise :class:`ConfigError` naming both sets unless ``objects`` is the set ``trained`` was made for.

    Same ids, and per id the same mesh hash (or, after a float32 file round trip, the same vertex count and
    bbox corners within :data:`GEOMETRY_TOL_M`).
    """
    here = object_record(objects, trained.get("keypoint_type", "bbox"))
    problems = []
    if here["obj_ids"] != list(trained["obj_ids"]):
        problems.append(f"object ids differ ({list(trained['obj_ids'])} vs {here['obj_ids']})")
    else:
        for k, oid in enumerate(here["obj_ids"]):
            if here["mesh_hashes"][k] == trained["mesh_hashes"][k]:
                continue
            same = (here["num_vertices"][k] == trained["num_vertices"][k] and np.allclose(
                here["bbox_corners"][k], trained["bbox_corners"][k], atol=GEOMETRY_TOL_M, rtol=0.0))
            if not same:
                problems.append(f"object {oid} mesh differs (hash {trained['mesh_hashes'][k][:10]} vs "
                                f"{here['mesh_hashes'][k][:10]})")
    if problems:
        raise ConfigError(f"{where} was trained for objects [{_describe(trained)}] but the objects given are "
                          f"[{_describe(here)}]: {'; '.join(problems)}. {hint}")


def save_checkpoint(path: str | Path, ckpt: dict[str, Any]) -> Path:
    """Write ``ckpt`` atomically (temporary file in the same folder, then rename)."""
    import torch

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.tmp{os.getpid()}")
    try:
        torch.save(ckpt, tmp)
        os.replace(tmp, path)
    finally:
        if tmp.exists():
            tmp.unlink()
    return path


def load_checkpoint(path: str | Path, map_location: str = "cpu", *, fmt: str) -> dict[str, Any]:
    """Read a checkpoint with ``weights_only=True``; ``fmt`` is the expected ``format`` entry.

    Raises:
        ConfigError: Missing file, unreadable, or a checkpoint of another format.
    """
    import torch

    path = Path(path)
    if not path.is_file():
        raise ConfigError(f"checkpoint {str(path)!r} does not exist")
    try:
        ckpt = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as exc:  # noqa: BLE001 - any unpickling failure is a bad file
        raise ConfigError(f"checkpoint {str(path)!r} could not be read: {type(exc).__name__}: {exc}") from exc
    if not isinstance(ckpt, dict) or ckpt.get("format") != fmt:
        got = ckpt.get("format") if isinstance(ckpt, dict) else type(ckpt).__name__
        kind = KINDS.get(fmt, fmt.split("/")[0].removeprefix("simtest-"))
        raise ConfigError(f"{path}: not a {kind} checkpoint (format {got!r}, expected {fmt!r})")
    return ckpt
