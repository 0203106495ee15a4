"""BOP results CSV (pose estimates), as the BOP toolkit's ``inout.load_bop_results`` reads it.

Header ``scene_id,im_id,obj_id,score,R,t,time``; one row per estimate; ``R`` is the 3x3 rotation (model ->
camera) as 9 space-separated floats, row-major; ``t`` the translation as 3 space-separated floats in
**millimetres**; ``time`` the seconds spent on the whole image (-1 if unknown), the same on every row of one
image. Inside simtest the rows are :class:`simtest.metrics.bop19.ResultRow` with ``t`` in metres; this
module converts at the file boundary (``MM_PER_M`` of :mod:`simtest.io.bop`).
"""

from __future__ import annotations

import csv
import io
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from simtest.errors import DatasetError
from simtest.io.bop import MM_PER_M
from simtest.io.files import atomic_write_text
from simtest.metrics.bop19 import ResultRow

__all__ = ["RESULTS_HEADER", "write_bop_results", "read_bop_results", "format_bop_results"]

#: Column names of a BOP results file, in order.
RESULTS_HEADER: tuple[str, ...] = ("scene_id", "im_id", "obj_id", "score", "R", "t", "time")


def _floats(values: Iterable[float]) -> str:
    return " ".join(repr(float(v)) for v in values)


def format_bop_results(rows: Iterable[ResultRow]) -> str:
    """The text of a BOP results CSV for ``rows`` (translations in metres, written in millimetres)."""
    out = [",".join(RESULTS_HEADER)]
    for r in rows:
        R = np.asarray(r.R, dtype=np.float64).reshape(-1)
        t_mm = np.asarray(r.t, dtype=np.float64).reshape(-1) * MM_PER_M
        out.append(f"{int(r.scene_id)},{int(r.im_id)},{int(r.obj_id)},{float(r.score)!r},{_floats(R)},"
                   f"{_floats(t_mm)},{float(r.time)!r}")
    return "\n".join(out) + "\n"


def write_bop_results(path: str | Path, rows: Iterable[ResultRow]) -> Path:
    """Write pose estimates as a BOP results CSV (atomically).

    Args:
        path: Output file (``.csv``; the BOP toolkit expects ``METHOD_DATASET-SPLIT.csv`` names).
        rows: Estimates with ``t`` in metres; ``time`` is the per-image time in seconds (-1 if unknown).

    Returns:
        The path written.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(path, format_bop_results(rows))
    return path


def _parse_numbers(text: str, n: int, where: str, field: str) -> np.ndarray:
    parts = text.split()
    if len(parts) != n:
        raise DatasetError(f"{where}: field {field!r} must hold {n} space-separated numbers, got {len(parts)}: "
                           f"{text!r}")
    try:
        vals = np.array([float(p) for p in parts], dtype=np.float64)
    except ValueError:
        raise DatasetError(f"{where}: field {field!r} is not numeric: {text!r}") from None
    if not np.all(np.isfinite(vals)):
        raise DatasetError(f"{where}: field {field!r} has NaN or infinite values: {text!r}")
    return vals


def _parse_int(text: str, where: str, field: str) -> int:
    try:
        return int(text.strip())
    except ValueError:
        raise DatasetError(f"{where}: field {field!r} must be an integer, got {text!r}") from None


def _parse_float(text: str, where: str, field: str) -> float:
    try:
        v = float(text.strip())
    except ValueError:
        raise DatasetError(f"{where}: field {field!r} must be a number, got {text!r}") from None
    if not np.isfinite(v):
        raise DatasetError(f"{where}: field {field!r} must be finite, got {text!r}")
    return v


def read_bop_results(path: str | Path, check_rotation: bool = True) -> list[ResultRow]:
    """Read a BOP results CSV into estimates with ``t`` in metres.

    Args:
        path: The CSV file.
        check_rotation: Reject rotations that are not orthonormal with det +1 (tolerance 1e-3).

    Returns:
        The estimates in file order.

    Raises:
        DatasetError: Missing file, wrong header, or a malformed row; the message names the file, the line
            number (1-based, the header is line 1) and the field.
    """
    path = Path(path)
    if not path.is_file():
        raise DatasetError(f"{path}: results file not found")
    text = path.read_text()
    reader = csv.reader(io.StringIO(text))
    try:
        header = [h.strip() for h in next(reader)]
    except StopIteration:
        raise DatasetError(f"{path}: empty file; expected the header {','.join(RESULTS_HEADER)}") from None
    if tuple(header) != RESULTS_HEADER:
        raise DatasetError(f"{path}:1: header must be {','.join(RESULTS_HEADER)}, got {','.join(header)}")
    rows: list[ResultRow] = []
    times: dict[tuple[int, int], float] = {}
    for line_no, fields in enumerate(reader, start=2):
        if not fields or all(not f.strip() for f in fields):
            continue
        where = f"{path}:{line_no}"
        if len(fields) != len(RESULTS_HEADER):
            raise DatasetError(f"{where}: expected {len(RESULTS_HEADER)} comma-separated fields "
                               f"({','.join(RESULTS_HEADER)}), got {len(fields)}")
        scene_id = _parse_int(fields[0], where, "scene_id")
        im_id = _parse_int(fields[1], where, "im_id")
        obj_id = _parse_int(fields[2], where, "obj_id")
        score = _parse_float(fields[3], where, "score")
        R = _parse_numbers(fields[4], 9, where, "R").reshape(3, 3)
        t_mm = _parse_numbers(fields[5], 3, where, "t")
        time = _parse_float(fields[6], where, "time")
        if check_rotation:
            dev = float(np.abs(R @ R.T - np.eye(3)).max())
            if dev > 1e-3 or np.linalg.det(R) < 0:
                raise DatasetError(f"{where}: field 'R' is not a rotation matrix (max |R R^T - I| = {dev:.2g}, "
                                   f"det = {np.linalg.det(R):.3f})")
        key = (scene_id, im_id)
        if key in times and time != times[key] and time >= 0 and times[key] >= 0:
            raise DatasetError(f"{where}: field 'time' is {time} but an earlier row of scene {scene_id}, image "
                               f"{im_id} has {times[key]}; BOP requires one time per image")
        times.setdefault(key, time)
        rows.append(ResultRow(scene_id=scene_id, im_id=im_id, obj_id=obj_id, score=score, R=R,
                                 t=t_mm / MM_PER_M, time=time))
    return rows
