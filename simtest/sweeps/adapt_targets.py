"""A sweep's per-target results with the factors a generator can aim at: for every target of one estimator's
pose cells, its condition, object, visible fraction, camera distance, elevation and in-plane angle, and whether
the estimate failed. Read from the sweep's files only (``cells/<estimator>/<condition>/pose/errors.csv`` and the
ground truth of the dataset each cell ran on), so ``simtest adapt`` works on any finished sweep folder.

Units: metres and degrees. A target *fails* when it was not matched or its ADD(-S) error exceeds 10 % of the
object's diameter (the sweep's ``add_s_or_add_01d`` score is the share that does not fail).
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from simtest.errors import DatasetError
from simtest.io.bop import pose_from_bop, read_scene_files
from simtest.io.bop_splits import dataset_split_dir
from simtest.io.files import read_csv
from simtest.sweeps.cells import cell_dir

__all__ = ["TargetResult", "view_factors", "read_targets", "sweep_estimators", "cell_dataset", "FAIL_THRESHOLD"]

#: A target fails when its ADD(-S) error exceeds this fraction of the object's diameter (or it is unmatched).
FAIL_THRESHOLD = 0.1


@dataclass(frozen=True)
class TargetResult:
    """One target of one pose cell: where it was seen from and whether the estimate failed.

    ``distance_m``: camera centre to object origin (metres); ``elevation_deg``: the camera's height angle above
    the table plane seen from the object; ``inplane_deg``: the camera's in-plane rotation (the angle of the
    world's up direction in the image from the image's up, degrees, the generator's ``shell`` roll)."""

    condition: str
    obj_id: int
    visib_fract: float
    distance_m: float
    elevation_deg: float
    inplane_deg: float
    failed: bool


def view_factors(R_w2c: np.ndarray, t_w2c_m: np.ndarray, R_m2c: np.ndarray, t_m2c_m: np.ndarray
                 ) -> tuple[float, float, float]:
    """``(distance_m, elevation_deg, inplane_deg)`` of an object pose ``(R_m2c, t_m2c_m)`` seen by a camera at
    ``(R_w2c, t_w2c_m)`` (world z up, translations in metres)."""
    del R_m2c  # the object's orientation does not enter these factors
    R_w2c = np.asarray(R_w2c, np.float64)
    cam_w = -R_w2c.T @ np.asarray(t_w2c_m, np.float64)
    obj_w = R_w2c.T @ (np.asarray(t_m2c_m, np.float64) - np.asarray(t_w2c_m, np.float64))
    v = cam_w - obj_w
    dist = float(np.linalg.norm(v))
    elevation = math.degrees(math.asin(float(np.clip(v[2] / max(dist, 1e-12), -1.0, 1.0))))
    up = R_w2c[:, 2]  # world z in the camera frame; image up is -y
    inplane = math.degrees(math.atan2(-up[0], -up[1]))
    return dist, elevation, inplane


def sweep_estimators(sweep_dir: str | Path) -> list[str]:
    """The estimator names of a sweep folder (its ``cells/`` subfolders with at least one pose cell)."""
    root = Path(sweep_dir) / "cells"
    if not root.is_dir():
        raise DatasetError(f"{str(sweep_dir)!r} is not a sweep folder: it has no cells/ (run simtest sweep first)")
    return sorted(p.name for p in root.iterdir() if p.is_dir() and any(p.glob("*/pose/cell.json")))


def _failed(row: dict) -> bool:
    try:
        err, diameter = float(row["add_s_or_add"]), float(row["diameter_m"])
    except (TypeError, ValueError):
        return True
    return str(row.get("matched", "1")) not in ("1", "True", "true") or not err <= FAIL_THRESHOLD * diameter


class _Views:
    """Camera and object poses of a dataset's images, read once per scene."""

    def __init__(self, dataset: Path, split: str | None) -> None:
        self.split = dataset_split_dir(dataset, split)
        self._scenes: dict[int, object] = {}

    def factors(self, scene_id: int, im_id: int, gt_id: int) -> tuple[float, float, float]:
        files = self._scenes.get(scene_id)
        if files is None:
            files = self._scenes[scene_id] = read_scene_files(self.split / f"{scene_id:06d}")
        cam = files.camera[str(im_id)]
        gt = files.gt[str(im_id)][gt_id]
        T_c = pose_from_bop(cam["cam_R_w2c"], cam["cam_t_w2c"])
        T_o = pose_from_bop(gt["cam_R_m2c"], gt["cam_t_m2c"])
        return view_factors(T_c.R, T_c.t, T_o.R, T_o.t)


def cell_dataset(sweep: Path, condition: str, cell: dict) -> Path:
    """The dataset a pose cell ran on: the sweep's own ``data/<condition>`` folder, else the recorded one."""
    local = sweep / "data" / condition
    if local.is_dir():
        return local
    recorded = Path(str(cell.get("dataset", "")))
    if recorded.is_dir():
        return recorded
    raise DatasetError(f"the dataset of condition {condition!r} is neither {str(local)!r} nor the recorded "
                       f"{str(recorded)!r}")


def read_targets(sweep_dir: str | Path, estimator: str) -> list[TargetResult]:
    """Every target of ``estimator``'s finished pose cells in a sweep folder, conditions in name order.

    Raises:
        DatasetError: Not a sweep folder, an unknown estimator (the sweep's are listed), no finished pose cell,
            or a cell's dataset missing.
    """
    sweep = Path(sweep_dir)
    names = sweep_estimators(sweep)
    if estimator not in names:
        raise DatasetError(f"estimator {estimator!r} has no pose cells in {str(sweep)!r}; its estimators: {names}")
    split = json.loads((sweep / "sweep_config.json").read_text()).get("dataset", {}).get("split") \
        if (sweep / "sweep_config.json").is_file() else None
    out: list[TargetResult] = []
    views: dict[Path, _Views] = {}
    for cdir in sorted((sweep / "cells" / estimator).iterdir()):
        pose = cell_dir(sweep, estimator, cdir.name, "pose")
        if not (pose / "cell.json").is_file() or not (pose / "errors.csv").is_file():
            continue
        data = cell_dataset(sweep, cdir.name, json.loads((pose / "cell.json").read_text()))
        v = views.setdefault(data, _Views(data, split))
        for row in read_csv(pose / "errors.csv"):
            d, el, ip = v.factors(int(row["scene_id"]), int(row["im_id"]), int(row["gt_id"]))
            out.append(TargetResult(cdir.name, int(row["obj_id"]), float(row["visib_fract"]), d, el, ip,
                                    _failed(row)))
    if not out:
        raise DatasetError(f"estimator {estimator!r} has no finished pose cell with targets in {str(sweep)!r}")
    return out
