"""The on-disk layout of a sweep's cells, and the tidy tables gathered from them.

A cell is (estimator, condition, kind) with kind ``pose`` or ``grasp``; it lives in
``OUT/cells/<estimator>/<condition>/<kind>/`` and is finished once its ``cell.json`` exists (written last,
atomically). :func:`write_tables` gathers every finished cell into ``results.csv`` (one row per target or
episode) and ``summary.csv`` (one row per metric, with its count ``n`` and 95 % interval,
:mod:`simtest.sweeps.uncertainty`), which is all :mod:`simtest.sweeps.report` reads.
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any

from simtest.io.files import atomic_write_json, read_csv, write_csv
from simtest.sweeps.uncertainty import Interval, pose_intervals

__all__ = ["cell_dir", "is_finished", "finish_cell", "collect", "write_tables", "labels", "Scores", "RESULT_COLUMNS",
           "SUMMARY_COLUMNS", "RESULTS_FILE", "SUMMARY_FILE"]

RESULTS_FILE = "results.csv"
SUMMARY_FILE = "summary.csv"
RESULT_COLUMNS = ["estimator", "condition", "factor", "level", "severity", "kind", "scene_id", "im_id", "obj_id",
                  "episode", "target_name", "matched", "visib_fract", "diameter_m", "add_m", "adi_m",
                  "add_s_or_add_m", "re_deg", "re_sym_deg", "te_m", "mssd_m", "success", "reason"]
#: ``n``: the targets (pose) or episodes (grasp) a score is over; ``ci95_low`` / ``ci95_high``: its 95 % interval,
#: in the unit of ``value``; ``interval``: how it was made (``wilson`` | ``bootstrap``;
#: :mod:`simtest.sweeps.uncertainty`), empty for values without one (counts, timings, AP).
SUMMARY_COLUMNS = ["estimator", "condition", "factor", "level", "severity", "kind", "metric", "value", "n",
                   "ci95_low", "ci95_high", "interval"]
_MARKER = "cell.json"


def cell_dir(out: str | Path, estimator: str, condition: str, kind: str) -> Path:
    """Folder of one cell of the sweep in ``out``."""
    return Path(out) / "cells" / estimator / condition / kind


def is_finished(cdir: Path) -> bool:
    """Whether the cell in ``cdir`` finished (its ``cell.json`` exists)."""
    return (cdir / _MARKER).exists()


def finish_cell(cdir: Path, record: dict[str, Any]) -> None:
    """Mark the cell finished by writing ``record`` to its ``cell.json`` (atomically, last)."""
    atomic_write_json(cdir / _MARKER, record)


def _read_cell(cdir: Path) -> dict[str, Any] | None:
    return json.loads((cdir / _MARKER).read_text()) if is_finished(cdir) else None


def _interval_columns(iv: Interval | None) -> dict[str, Any]:
    if iv is None:
        return {"n": "", "ci95_low": "", "ci95_high": "", "interval": ""}
    return {"n": iv.n, "ci95_low": "" if math.isnan(iv.low) else iv.low,
            "ci95_high": "" if math.isnan(iv.high) else iv.high, "interval": iv.method}


def _pose_rows(base: dict, cdir: Path, cell: dict) -> tuple[list[dict], list[dict]]:
    errors = read_csv(cdir / "errors.csv") if (cdir / "errors.csv").exists() else []
    intervals = pose_intervals(cell["overall"], errors)
    summary = [{**base, "kind": "pose", "metric": key, "value": "" if value is None else value,
                **_interval_columns(intervals.get(key))}
               for key, value in cell["overall"].items() if isinstance(value, (int, float)) or value is None]
    results = []
    if errors:
        for r in errors:
            results.append({**base, "kind": "pose", "scene_id": r["scene_id"], "im_id": r["im_id"],
                            "obj_id": r["obj_id"], "matched": r["matched"], "visib_fract": r["visib_fract"],
                            "diameter_m": r["diameter_m"], "add_m": r["add"], "adi_m": r["adi"],
                            "add_s_or_add_m": r["add_s_or_add"], "re_deg": r["re"], "re_sym_deg": r["re_sym"],
                            "te_m": r["te"], "mssd_m": r["mssd"]})
    return results, summary


def _grasp_rows(base: dict, cdir: Path, cell: dict) -> tuple[list[dict], list[dict]]:
    s = cell["summary"]
    rate = Interval(int(s["episodes"]), float(s["ci95"][0]), float(s["ci95"][1]), "wilson")
    summary = [{**base, "kind": "grasp", "metric": key, "value": s[key],
                **_interval_columns(rate if key == "success_rate" else None)}
               for key in ("success_rate", "episodes", "successes")]
    results = []
    if (cdir / "episodes.csv").exists():
        for r in read_csv(cdir / "episodes.csv"):
            results.append({**base, "kind": "grasp", "episode": r["episode"], "obj_id": r["target_obj_id"],
                            "target_name": r["target_name"], "add_s_or_add_m": r["add_s"], "re_deg": r.get("re_raw_deg") or r.get("re_deg", ""),
                            "re_sym_deg": r.get("re_sym_deg", ""), "te_m": r["te"], "mssd_m": r["mssd"], "success": r["success"], "reason": r["reason"]})
    return results, summary


def labels(out: str | Path, estimators: list[str], conds: list) -> dict[str, str]:
    """``{name: label}``: the label its finished pose cells recorded (``NAME (GT masks)`` for an estimator
    given ground-truth masks), else the name."""
    found = {}
    for est in estimators:
        for cond in conds:
            cell = _read_cell(cell_dir(out, est, cond.name, "pose"))
            if cell is not None and cell.get("label"):
                found[est] = str(cell["label"])
                break
    return {est: found.get(est, est) for est in estimators}


def collect(out: str | Path, estimators: list[str], conds: list) -> tuple[list[dict], list[dict]]:
    """``(results, summary)`` rows of every finished cell, conditions in table order; the ``estimator``
    column holds the estimator's label (:func:`labels`).

    Args:
        out: Sweep folder.
        estimators: Estimator labels, in order.
        conds: :class:`simtest.sweeps.grid.Condition` objects (``name``, ``factor``, ``level``, ``severity``).
    """
    results, summary = [], []
    names = labels(out, estimators, conds)
    for cond in conds:
        base = {"condition": cond.name, "factor": cond.factor, "level": cond.level,
                "severity": "" if cond.severity is None else cond.severity}
        for est in estimators:
            for kind, rows_of in (("pose", _pose_rows), ("grasp", _grasp_rows)):
                cdir = cell_dir(out, est, cond.name, kind)
                cell = _read_cell(cdir)
                if cell is not None:
                    r, s = rows_of({**base, "estimator": names[est]}, cdir, cell)
                    results += r
                    summary += s
    return results, summary


def write_tables(out: str | Path, estimators: list[str], conds: list) -> dict[str, Path]:
    """Write ``results.csv`` and ``summary.csv`` of the finished cells; returns their paths."""
    out = Path(out)
    results, summary = collect(out, estimators, conds)
    write_csv(out / RESULTS_FILE, results, RESULT_COLUMNS)
    write_csv(out / SUMMARY_FILE, summary, SUMMARY_COLUMNS)
    return {"results": out / RESULTS_FILE, "summary": out / SUMMARY_FILE}


def _number(text: Any) -> float:
    try:
        return float(text)
    except (TypeError, ValueError):
        return math.nan


class Scores:
    """``summary.csv`` rows looked up by (estimator, condition, kind, metric): the value and its
    :class:`~simtest.sweeps.uncertainty.Interval` (NaN and ``n = 0`` where the sweep has no such score)."""

    def __init__(self, summary: list[dict[str, Any]]) -> None:
        self._rows = {(r["estimator"], r["condition"], r["kind"], r["metric"]): r for r in summary}

    def get(self, estimator: str, condition: str, kind: str, metric: str) -> tuple[float, Interval]:
        """``(value, interval)`` of one score."""
        r = self._rows.get((estimator, condition, kind, metric))
        if r is None:
            return math.nan, Interval(0)
        n = _number(r.get("n"))
        return _number(r["value"]), Interval(0 if math.isnan(n) else int(n), _number(r.get("ci95_low")),
                                             _number(r.get("ci95_high")), str(r.get("interval") or ""))

    def value(self, estimator: str, condition: str, kind: str, metric: str) -> float:
        """The value of one score (NaN if absent)."""
        return self.get(estimator, condition, kind, metric)[0]
