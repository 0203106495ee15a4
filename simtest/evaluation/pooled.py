"""Several evaluation runs of one estimator pooled into one score: the protocol for numbers that must hold on
unseen data (one estimator, several test sets generated with seeds never used while it was built).

Each run folder is one ``simtest eval`` output (its ``errors.csv``: one row per target). Pooling concatenates
the targets of all runs; a scene is identified by ``(run, scene_id)``, so the 95 % interval of the pooled score
is a percentile bootstrap over those scenes (:func:`simtest.metrics.intervals.cluster_bootstrap_interval`):
targets of one scene share its clutter, lighting and camera path and are not independent, and scenes differ
more than a binomial interval over targets admits. Each run is also scored alone (its Wilson interval over
targets and, where it has several scenes, its own scene bootstrap), with the spread between runs.
"""

from __future__ import annotations

import csv
import json
import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from simtest.errors import DatasetError
from simtest.evaluation.scoring import aggregate
from simtest.io.files import atomic_write_text, dump_json
from simtest.metrics.registry import metric

__all__ = ["PooledScore", "read_error_rows", "pool_runs", "pooled_markdown", "write_pooled"]

#: The per-target hit metrics a pooled table shows (fractions of targets; registry keys).
POOLED_KEYS = ("add_s_or_add_01d", "adds_lt_2cm", "acc_pi_6", "5deg5cm")
_FLOATS = ("visib_fract", "diameter_m", "adi", "add_s_or_add", "re_sym", "te")


@dataclass(frozen=True)
class PooledScore:
    """Scores of several runs and of their union.

    Attributes:
        runs: The run folders, in the order given.
        per_run: Per run, :func:`simtest.evaluation.scoring.aggregate` of its targets.
        pooled: The aggregate over all targets, with ``ci95_scenes`` over ``(run, scene_id)``.
        estimators: The estimator name each run's ``metrics.json`` records (``"?"`` if none).
    """

    runs: tuple[Path, ...]
    per_run: tuple[dict[str, Any], ...]
    pooled: dict[str, Any]
    estimators: tuple[str, ...]

    def spread(self, key: str = "add_s_or_add_01d") -> float:
        """Max - min of ``key`` over the runs (a fraction)."""
        vals = [r[key] for r in self.per_run]
        return float(max(vals) - min(vals))

    def to_json(self) -> dict[str, Any]:
        return {"runs": [str(r) for r in self.runs], "estimators": list(self.estimators),
                "per_run": list(self.per_run), "pooled": self.pooled,
                "spread": {k: self.spread(k) for k in POOLED_KEYS}}


def read_error_rows(run: str | Path) -> list[dict[str, Any]]:
    """The per-target rows of one run's ``errors.csv`` (numbers parsed; ``matched`` a bool).

    Raises:
        DatasetError: the folder has no ``errors.csv``, or a row lacks a column or holds a non-number.
    """
    path = Path(run) / "errors.csv"
    if not path.is_file():
        raise DatasetError(f"{path}: not found; pass folders written by `simtest eval` (each holds errors.csv)")
    rows = []
    with path.open(newline="") as f:
        for line, raw in enumerate(csv.DictReader(f), start=2):
            try:
                row: dict[str, Any] = {k: float(raw[k]) if raw[k].strip() else math.nan for k in _FLOATS}
                row["matched"] = raw["matched"].strip() in ("1", "True", "true")
                row["scene_id"] = int(raw["scene_id"])
                row["obj_id"] = int(raw["obj_id"])
                ready = (raw.get("grasp_ready") or "").strip()
                row["grasp_ready"] = None if ready == "" else ready in ("1", "True", "true")
            except KeyError as exc:
                raise DatasetError(f"{path}: line {line} has no column {exc.args[0]!r}") from None
            except ValueError as exc:
                raise DatasetError(f"{path}: line {line}: {exc}") from None
            rows.append(row)
    if not rows:
        raise DatasetError(f"{path}: no targets")
    return rows


def _estimator(run: Path) -> str:
    try:
        meta = json.loads((run / "metrics.json").read_text())
    except (OSError, ValueError):
        return "?"
    return str((meta.get("settings") or {}).get("estimator") or "?")


def pool_runs(runs: list[str | Path]) -> PooledScore:
    """Score each run and their union (see the module docstring).

    Raises:
        DatasetError: fewer than one run, a run folder given twice, or a run without ``errors.csv``.
    """
    paths = [Path(r) for r in runs]
    if not paths:
        raise DatasetError("pool: no run folders given")
    seen = {p.resolve() for p in paths}
    if len(seen) != len(paths):
        raise DatasetError(f"pool: a run folder is given twice: {[str(p) for p in paths]}")
    per_run, union = [], []
    for k, p in enumerate(paths):
        rows = read_error_rows(p)
        per_run.append(aggregate(rows))
        union += [{**r, "scene_id": (k, r["scene_id"])} for r in rows]
    return PooledScore(runs=tuple(paths), per_run=tuple(per_run), pooled=aggregate(union),
                       estimators=tuple(_estimator(p) for p in paths))


def _pct(x: float) -> str:
    return "-" if x is None or not math.isfinite(x) else f"{100 * x:.1f}"


def _interval(ci: list[float] | None) -> str:
    return "" if not ci else f" [{100 * ci[0]:.1f}, {100 * ci[1]:.1f}]"


def pooled_markdown(score: PooledScore) -> str:
    """The pooled table: one row per run (Wilson intervals over targets) and the pooled row (bootstrap over
    scenes), then the spread between runs."""
    labels = {k: metric(k).label for k in POOLED_KEYS}
    head = "| run | estimator | targets | scenes | " + " | ".join(f"{labels[k]} [%]" for k in POOLED_KEYS) + " |"
    lines = [head, "|" + "---|" * 4 + "---:|" * len(POOLED_KEYS)]
    for path, est, m in zip(score.runs, score.estimators, score.per_run):
        cells = [_pct(m[k]) + _interval(m["ci95"].get(k)) for k in POOLED_KEYS]
        lines.append(f"| {path} | {est} | {m['num_targets']} | {m.get('num_scenes', 1)} | " + " | ".join(cells) + " |")
    p = score.pooled
    cells = [f"**{_pct(p[k])}**" + _interval((p.get("ci95_scenes") or {}).get(k)) for k in POOLED_KEYS]
    lines.append(f"| **pooled** | | {p['num_targets']} | {p.get('num_scenes', 1)} | " + " | ".join(cells) + " |")
    lines += ["", "Run rows: 95 % Wilson intervals over targets. Pooled row: 95 % percentile bootstrap over the "
              "scenes of all runs (a scene = run and scene id). Spread (max - min over runs): "
              + ", ".join(f"{labels[k]} {100 * score.spread(k):.1f} points" for k in POOLED_KEYS) + "."]
    return "\n".join(lines) + "\n"


def write_pooled(score: PooledScore, out: str | Path) -> tuple[Path, Path]:
    """``pooled.json`` and ``pooled.md`` into ``out`` (atomic writes); returns their paths."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    j, m = out / "pooled.json", out / "pooled.md"
    atomic_write_text(j, dump_json(score.to_json()))
    atomic_write_text(m, pooled_markdown(score))
    return j, m
