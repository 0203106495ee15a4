"""Tolerance maps: grasp success against a pose error of exact size along one axis at a time, per object.

For every graspable object of a set, the ``oracle`` is given one error along one axis of
:data:`~simtest.estimators.oracle.ERROR_AXES` (translation along the object's x, y, z and along the camera's
viewing ray, millimetres; rotation about the object's x, y, z, degrees), for a grid of magnitudes; each
(object, axis, magnitude) cell runs ``episodes_per_cell`` closed-loop episodes (target alone on the table, L0).

Seeding: episode ``j`` of object ``obj_id`` resets its env with the seed of ``SeedSequence`` child
``(obj_id, j)`` of the master seed, and the oracle's random sign of the error comes from that seed too, so
episode ``j`` is the same scene with the same error direction in every cell of its object: the cells of a
curve are paired comparisons. The zero-error cell is run once per object and shared by its axes. A unit is one
episode, whichever worker runs it: the same seed gives the same ``tolerance.csv`` with any number of workers
and on either back end.

Outputs (:func:`write_tolerance`): ``episodes.csv`` (one row per episode), ``tolerance.csv`` (one row per
cell: successes, episodes, rate and 95 % Wilson interval) and ``tolerance.json`` (per object and axis the
largest error keeping success >= 90 %, :func:`simtest.metrics.tolerance.largest_tolerated`; and, since even
the exact pose fails now and then, ``tolerated_relative``: the largest keeping success >= 90 % of the object's
zero-error rate).

Symmetric objects: a rotation about an axis of continuous symmetry (a can's z) moves no surface point, so it
is no error at all; such axes are marked ``continuous`` in the ``symmetry`` column (their cells still run, as
a check). Discrete symmetries (a box turned 180 degrees) are noted with their angles.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from simtest.backend import RunStats
from simtest.envs.oracle_episodes import EpisodeSetup, OracleUnit, check_objects, episode_seed_of, run_oracle_units
from simtest.errors import ConfigError
from simtest.estimators.oracle import ERROR_AXES
from simtest.io.files import atomic_write_json, jsonable, write_csv
from simtest.metrics.intervals import wilson_interval
from simtest.metrics.tolerance import TOLERANCE_LEVEL, largest_tolerated

__all__ = ["ToleranceConfig", "ToleranceResult", "run_tolerance", "write_tolerance", "axis_symmetry",
           "TRANS_MM", "ROT_DEG", "CELL_COLUMNS", "EPISODE_COLUMNS", "axis_unit"]

#: Default translation magnitudes, millimetres.
TRANS_MM: tuple[float, ...] = (0, 5, 10, 15, 20, 30, 40, 60)
#: Default rotation magnitudes, degrees.
ROT_DEG: tuple[float, ...] = (0, 5, 10, 20, 30, 45, 60, 90)
#: Columns of ``tolerance.csv``.
CELL_COLUMNS = ["object", "obj_id", "axis", "unit", "magnitude", "successes", "episodes", "success_rate",
                "ci95_lo", "ci95_hi", "symmetry"]
#: Columns of ``episodes.csv`` (errors in m and degrees, times in s).
EPISODE_COLUMNS = ["object", "obj_id", "axis", "magnitude", "episode", "seed", "success", "reason", "add_s",
                   "re_sym_deg", "te", "mssd", "wall_s"]


def axis_unit(axis: str) -> str:
    """``"mm"`` for a translation axis, ``"deg"`` for a rotation axis."""
    return "mm" if axis.startswith("t_") else "deg"


@dataclass(frozen=True)
class ToleranceConfig:
    """What a tolerance map measures.

    Attributes:
        setup: Object set, camera size and back end (:class:`~simtest.envs.oracle_episodes.EpisodeSetup`).
        targets: obj_ids or names of the objects to map (empty: every graspable object of the set).
        axes: Axes of :data:`~simtest.estimators.oracle.ERROR_AXES` to map.
        trans_mm: Magnitudes of the translation axes, millimetres (>= 0).
        rot_deg: Magnitudes of the rotation axes, degrees (>= 0).
        episodes_per_cell: Episodes per (object, axis, magnitude).
        seed: Master seed.
        level: Success rate a tolerated error keeps.
    """

    setup: EpisodeSetup = EpisodeSetup()
    targets: tuple = ()
    axes: tuple[str, ...] = ERROR_AXES
    trans_mm: tuple[float, ...] = TRANS_MM
    rot_deg: tuple[float, ...] = ROT_DEG
    episodes_per_cell: int = 10
    seed: int = 0
    level: float = TOLERANCE_LEVEL

    def check(self) -> None:
        """Raise :class:`ConfigError` naming a bad field, its value and what is allowed."""
        bad = [a for a in self.axes if a not in ERROR_AXES]
        if bad or not self.axes:
            raise ConfigError(f"axes must be a non-empty list of {', '.join(ERROR_AXES)}; got {list(self.axes)!r}")
        for name, grid in (("trans_mm", self.trans_mm), ("rot_deg", self.rot_deg)):
            if not grid or any(not (isinstance(m, (int, float)) and math.isfinite(m) and m >= 0) for m in grid):
                raise ConfigError(f"{name} must be a non-empty list of finite magnitudes >= 0, got {list(grid)!r}")
            if 0 not in grid:
                raise ConfigError(f"{name} must include 0 (the zero-error cell every curve starts at), got "
                                  f"{list(grid)!r}")
        if self.episodes_per_cell < 1:
            raise ConfigError(f"episodes_per_cell must be >= 1, got {self.episodes_per_cell!r}")
        if self.seed < 0:
            raise ConfigError(f"seed must be >= 0, got {self.seed!r}")
        if not 0.0 < self.level <= 1.0:
            raise ConfigError(f"level must be in (0, 1], got {self.level!r}")

    def grid(self, axis: str) -> list[float]:
        """The sorted magnitudes of ``axis`` (mm or degrees), duplicates removed."""
        return sorted({float(m) for m in (self.trans_mm if axis.startswith("t_") else self.rot_deg)})

    def to_dict(self) -> dict:
        return {**{k: v for k, v in self.__dict__.items() if k != "setup"}, "setup": self.setup.record()}


@dataclass
class ToleranceResult:
    """Episode rows, cell rows (:data:`CELL_COLUMNS`), the tolerance summary and the timing of a map."""

    episodes: list[dict]
    cells: list[dict]
    summary: dict
    wall_s: float
    run: RunStats


def axis_symmetry(obj: Any, axis: str) -> str:
    """``"continuous"`` when ``axis`` is a rotation about an axis of continuous symmetry of ``obj`` (through its
    origin), ``"discrete 180 deg"`` (the angles) when discrete symmetries turn about it, else ``""``."""
    if not axis.startswith("r_"):
        return ""
    e = np.eye(3)["xyz".index(axis[-1])]
    for s in getattr(obj, "symmetries_continuous", ()):
        a = np.asarray(s.axis, dtype=np.float64)
        a = a / np.linalg.norm(a)
        off = np.asarray(s.offset, dtype=np.float64)
        if abs(abs(float(a @ e)) - 1.0) < 1e-6 and np.linalg.norm(off - (off @ a) * a) < 1e-6:
            return "continuous"
    angles = []
    for T in getattr(obj, "symmetries_discrete", ()):
        R = np.asarray(T, dtype=np.float64)[:3, :3]
        ang = math.degrees(math.acos(max(-1.0, min(1.0, (np.trace(R) - 1.0) / 2.0))))
        w, v = np.linalg.eigh(R + R.T) if ang > 179.0 else (None, None)
        ax = v[:, -1] if v is not None else np.array([R[2, 1] - R[1, 2], R[0, 2] - R[2, 0], R[1, 0] - R[0, 1]])
        if ang > 1e-3 and abs(abs(float(ax @ e)) / max(np.linalg.norm(ax), 1e-12) - 1.0) < 1e-4:
            angles.append(round(ang))
    return f"discrete {', '.join(str(a) for a in sorted(set(angles)))} deg" if angles else ""


def _units(cfg: ToleranceConfig, objs: list) -> list[OracleUnit]:
    units = []
    for o in objs:
        cells = [("none", 0.0)] + [(a, m) for a in cfg.axes for m in cfg.grid(a) if m > 0]
        for axis, mag in cells:
            opts = (("seed", cfg.seed),) if axis == "none" else (
                ("seed", cfg.seed), ("error_axis", axis), ("error", mag))
            for j in range(cfg.episodes_per_cell):
                units.append(OracleUnit(obj_id=int(o.obj_id), seed=episode_seed_of(cfg.seed, int(o.obj_id), j),
                                        options=opts, tags=(("object", o.name), ("obj_id", int(o.obj_id)),
                                                            ("axis", axis), ("magnitude", mag), ("episode", j))))
    return units


def _cells(cfg: ToleranceConfig, objs: list, rows: list[dict]) -> list[dict]:
    """One row per (object, axis, magnitude); the zero-error episodes count in every axis."""
    cells = []
    for o in objs:
        mine = [r for r in rows if r["obj_id"] == o.obj_id]
        for axis in cfg.axes:
            sym = axis_symmetry(o, axis)
            for mag in cfg.grid(axis):
                hits = [r for r in mine if (r["axis"] == "none" if mag == 0 else
                                            (r["axis"] == axis and r["magnitude"] == mag))]
                k, n = sum(bool(r["success"]) for r in hits), len(hits)
                lo, hi = wilson_interval(k, n)
                cells.append({"object": o.name, "obj_id": int(o.obj_id), "axis": axis, "unit": axis_unit(axis),
                              "magnitude": mag, "successes": k, "episodes": n, "success_rate": k / n if n else 0.0,
                              "ci95_lo": lo, "ci95_hi": hi, "symmetry": sym})
    return cells


def _summary(cfg: ToleranceConfig, objs: list, cells: list[dict]) -> dict:
    out: dict[str, Any] = {}
    for o in objs:
        axes = {}
        for axis in cfg.axes:
            mine = [c for c in cells if c["obj_id"] == o.obj_id and c["axis"] == axis]
            curve = ([c["magnitude"] for c in mine], [c["successes"] for c in mine], [c["episodes"] for c in mine])
            tol = largest_tolerated(*curve, cfg.level)
            zero = mine[0]["success_rate"]  # the grid starts at 0 (checked)
            rel = largest_tolerated(*curve, cfg.level * zero) if zero > 0 else None
            axes[axis] = {"unit": axis_unit(axis), "tolerated": tol.tolerated, "first_below": tol.first_below,
                          "reaches_zero": tol.reaches_zero, "symmetry": mine[0]["symmetry"],
                          "tolerated_relative": None if rel is None else rel.tolerated}
            base = (mine[0]["successes"], mine[0]["episodes"])
        out[o.name] = {"obj_id": int(o.obj_id), "symmetry": o.symmetry_label(),
                       "diameter_mm": round(float(o.diameter) * 1000, 1),
                       "zero_error": {"successes": base[0], "episodes": base[1]}, "axes": axes}
    return out


def run_tolerance(cfg: ToleranceConfig, *, progress: bool = True) -> ToleranceResult:
    """Run every episode of the map (see the module doc) and tabulate it.

    Raises:
        ConfigError: A bad field of ``cfg`` or an object that is not a graspable object of the set.
        BackendError: Episodes lost with their workers beyond the retries.
    """
    cfg.check()
    objs = check_objects(cfg.setup, cfg.targets)
    units = _units(cfg, objs)
    stats = RunStats()
    t0 = time.perf_counter()
    rows = list(run_oracle_units(cfg.setup, units, progress=progress, desc="tolerance", stats=stats))
    wall = time.perf_counter() - t0
    rows.sort(key=lambda r: (r["obj_id"], ERROR_AXES.index(r["axis"]) if r["axis"] in ERROR_AXES else -1,
                             r["magnitude"], r["episode"]))
    cells = _cells(cfg, objs, rows)
    summary = {"level": cfg.level, "objects": _summary(cfg, objs, cells), "config": cfg.to_dict(),
               "episodes": len(rows), "wall_s": wall, "episodes_per_s": len(rows) / wall if wall > 0 else None,
               "run": stats.record(cfg.setup.workers)}
    return ToleranceResult(rows, cells, summary, wall, stats)


def write_tolerance(result: ToleranceResult, out: str | Path) -> dict[str, Path]:
    """Write ``episodes.csv``, ``tolerance.csv`` and ``tolerance.json`` into ``out`` (made if absent)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"episodes": out / "episodes.csv", "tolerance": out / "tolerance.csv", "json": out / "tolerance.json"}
    write_csv(paths["episodes"], result.episodes, EPISODE_COLUMNS)
    write_csv(paths["tolerance"], result.cells, CELL_COLUMNS)
    atomic_write_json(paths["json"], jsonable(result.summary))
    return paths
