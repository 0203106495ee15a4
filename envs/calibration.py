"""Metric calibration: which pose-error metric predicts grasp success, and at which threshold.

Episodes of the ``oracle`` with random errors: in episode ``j`` of object ``obj_id`` (env seed from
``SeedSequence`` child ``(obj_id, j, 1)`` of the master seed) the oracle is off by exactly ``T`` millimetres in
a uniformly random direction and ``R`` degrees about a uniformly random axis (its ``"fixed"`` mode), with ``T``
uniform in ``[0, max_trans_mm]`` and ``R`` uniform in ``[0, max_rot_deg]`` drawn from that child too. The
occlusion level cycles over ``occlusions`` (L0-L2 by default). Every episode's errors are scored by each
metric of :data:`METRICS`, and each metric's error as a predictor of success is summarised
(:mod:`simtest.metrics.calibration`): ROC AUC with a bootstrap interval, the best-separating threshold, the
largest threshold whose correct episodes still succeed >= 90 % of the time, and the success rate of the
episodes it calls correct at BOP's own thresholds. The oracle runs keep their records as they were, without
VSD (their 64 x 48 depth is too coarse for it).

With ``estimators`` (names ``simtest grasp --estimator`` takes, e.g. ``icp``, ``segicp``, ``keypoints``) the
errors are those the real estimators make: episode ``j`` of object ``obj_id`` is the same scene (the same env
seed, child ``(obj_id, j, 1)``) for every estimator and in the oracle run, the estimators are pooled (an
``estimator`` column in the episode rows), and the table is computed over the pool, with per estimator its
successes and AUC (:data:`ESTIMATOR_COLUMNS`). An episode in which the estimator was asked and gave no usable
estimate for the target (``no_estimate``, ``estimator_error``, ``estimator_timeout``) is a failure with an
infinite error in every metric; an episode that ended before the estimator was asked (a collision on the way
to the observation pose) has no error and is left out of the metrics. VSD (:data:`VSD_METRICS`) is computed
against the depth image the estimator saw.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from simtest.backend import RunStats
from simtest.envs.oracle_episodes import EpisodeSetup, OracleUnit, check_objects, episode_seed_of, run_oracle_units
from simtest.errors import ConfigError
from simtest.io.files import atomic_write_json, jsonable, write_csv
from simtest.metrics.bop19 import MSPD_THETAS, MSSD_THETAS, VSD_TAUS, VSD_THETAS
from simtest.metrics.calibration import best_threshold, bootstrap_auc_interval, roc_auc, success_below
from simtest.metrics.intervals import wilson_interval
from simtest.metrics.tolerance import TOLERANCE_LEVEL
from simtest.rng import child_rng

__all__ = ["CalibrationConfig", "CalibrationResult", "METRICS", "VSD_METRICS", "run_calibration", "calibrate_rows",
           "metric_values", "write_calibration", "CALIBRATION_COLUMNS", "THRESHOLD_COLUMNS", "EPISODE_COLUMNS",
           "ESTIMATOR_EPISODE_COLUMNS", "ESTIMATOR_COLUMNS", "MISS_REASONS", "estimator_table"]


def _recall(errors: np.ndarray, thetas: tuple[float, ...]) -> np.ndarray:
    """1 - the fraction of ``thetas`` an error is below (``1 - AR`` of one estimate: an error, 0 is best)."""
    return 1.0 - np.mean([errors < t for t in thetas], axis=0)


@dataclass(frozen=True)
class _Metric:
    key: str
    label: str
    unit: str
    value: Callable[[dict], float]  # the metric's error of one episode row (diameter_m added)
    bop: tuple[float, ...] = ()  # BOP's correctness thresholds, in the metric's unit


def _mssd_d(r: dict) -> float:
    return r["mssd"] / r["diameter_m"]


#: The metrics calibrated: key, label, unit, how an episode's value is made, BOP's thresholds.
METRICS: tuple[_Metric, ...] = (
    _Metric("add_s_d", "ADD(-S) / diameter", "", lambda r: r["add_s"] / r["diameter_m"], (0.1,)),
    _Metric("mssd_d", "MSSD / diameter", "", _mssd_d, MSSD_THETAS),
    _Metric("mspd", "MSPD (px @ 640)", "px", lambda r: r["mspd"], MSPD_THETAS),
    _Metric("re_sym", "re (symmetry-aware)", "deg", lambda r: r["re_sym_deg"]),
    _Metric("te", "te", "mm", lambda r: 1000.0 * r["te"]),
    _Metric("one_minus_ar_mssd", "1 - AR_MSSD", "", lambda r: float(_recall(np.array([_mssd_d(r)]),
                                                                           MSSD_THETAS)[0])),
    _Metric("one_minus_ar_mspd", "1 - AR_MSPD", "", lambda r: float(_recall(np.array([r["mspd"]]),
                                                                           MSPD_THETAS)[0])),
    _Metric("one_minus_ar", "1 - mean(AR_MSSD, AR_MSPD)", "", lambda r: 0.5 * (
        float(_recall(np.array([_mssd_d(r)]), MSSD_THETAS)[0]) + float(_recall(np.array([r["mspd"]]),
                                                                               MSPD_THETAS)[0]))),
)


def _ar_vsd_error(r: dict) -> float:
    """1 - AR_VSD of one estimate: 1 - the fraction of (tau, theta) pairs with ``e_vsd(tau) < theta``."""
    if not math.isfinite(float(r["vsd"])):
        return float(r["vsd"])
    e = np.array([float(x) for x in str(r["vsd_taus"]).split()])
    return 1.0 - float(np.mean([e < th for th in VSD_THETAS]))


#: The VSD metrics, added when the episodes kept the observation's depth (runs of real estimators).
VSD_METRICS: tuple[_Metric, ...] = (
    _Metric("vsd", "VSD (mean over tau)", "", lambda r: float(r["vsd"])),
    _Metric("one_minus_ar_vsd", "1 - AR_VSD", "", _ar_vsd_error),
    _Metric("one_minus_ar_bop", "1 - mean(AR_VSD, AR_MSSD, AR_MSPD)", "", lambda r: (
        _ar_vsd_error(r) + 2.0 * METRICS[-1].value(r)) / 3.0),
)
#: Columns of ``calibration.csv``.
CALIBRATION_COLUMNS = ["metric", "label", "unit", "episodes", "successes", "auc", "auc_lo", "auc_hi",
                       "best_threshold", "youden", "tpr", "fpr", "threshold_90"]
#: Columns of ``calibration_thresholds.csv`` (success among the episodes a metric calls correct at BOP's
#: thresholds).
THRESHOLD_COLUMNS = ["metric", "threshold", "correct", "successes", "success_rate", "ci95_lo", "ci95_hi"]
#: Columns of ``calibration_episodes.csv``.
EPISODE_COLUMNS = ["object", "obj_id", "episode", "seed", "occlusion", "trans_mm", "rot_deg", "success", "reason",
                   "add_s", "re_sym_deg", "te", "mssd", "mspd", "wall_s"]
#: Columns of ``calibration_episodes.csv`` of a run of real estimators (``inf``: a miss).
ESTIMATOR_EPISODE_COLUMNS = ["estimator", "object", "obj_id", "episode", "seed", "occlusion", "success", "reason",
                             "add_s", "re_sym_deg", "te", "mssd", "mspd", "vsd", "vsd_taus", "visible_pixels",
                             "occluded_fraction", "wall_s"]
#: Columns of ``calibration_estimators.csv``: per metric and estimator, the episodes with a value, their
#: successes (95 % Wilson interval) and the estimator's own AUC.
ESTIMATOR_COLUMNS = ["metric", "estimator", "episodes", "successes", "success_rate", "ci95_lo", "ci95_hi", "auc"]
#: Episode outcomes in which the estimator was asked and gave no usable estimate: a failure with infinite error.
MISS_REASONS = ("no_estimate", "estimator_error", "estimator_timeout")
_ERROR_FIELDS = ("add_s", "re_deg", "re_sym_deg", "te", "mssd", "mspd", "vsd")


@dataclass(frozen=True)
class CalibrationConfig:
    """What a calibration run measures.

    Attributes:
        setup: Object set, camera size and back end (``setup.mspd`` is turned on).
        targets: obj_ids or names (empty: every graspable object of the set).
        episodes_per_object: Episodes per object.
        max_trans_mm, max_rot_deg: Upper ends of the uniform error sizes, millimetres and degrees.
        occlusions: Occlusion levels cycled over the episodes (``"L0".."L3"``).
        seed: Master seed.
        resamples: Bootstrap resamples of the AUC interval.
        level: Success rate of ``threshold_90``.
        estimators: Real estimators pooled, by the names ``simtest grasp --estimator`` takes (empty: the
            oracle with random errors); each runs ``episodes_per_object`` episodes per object.
        estimator_options: Options per estimator name (``{"icp": {"max_iterations": 20}}``).
    """

    setup: EpisodeSetup = EpisodeSetup(mspd=True)
    targets: tuple = ()
    episodes_per_object: int = 50
    max_trans_mm: float = 40.0
    max_rot_deg: float = 60.0
    occlusions: tuple[str, ...] = ("L0", "L1", "L2")
    seed: int = 0
    resamples: int = 1000
    level: float = TOLERANCE_LEVEL
    estimators: tuple[str, ...] = ()
    estimator_options: dict = field(default_factory=dict)

    def check(self) -> None:
        """Raise :class:`ConfigError` naming a bad field, its value and what is allowed."""
        if self.episodes_per_object < 2:
            raise ConfigError(f"episodes_per_object must be >= 2, got {self.episodes_per_object!r}")
        for name in ("max_trans_mm", "max_rot_deg"):
            v = getattr(self, name)
            if not (math.isfinite(v) and v >= 0):
                raise ConfigError(f"{name} must be a finite number >= 0, got {v!r}")
        bad = [o for o in self.occlusions if o not in ("L0", "L1", "L2", "L3")]
        if bad or not self.occlusions:
            raise ConfigError(f"occlusions must be a non-empty list of L0, L1, L2, L3; got {list(self.occlusions)!r}")
        if self.seed < 0:
            raise ConfigError(f"seed must be >= 0, got {self.seed!r}")
        if "oracle" in self.estimators or len(set(self.estimators)) != len(self.estimators):
            raise ConfigError(f"estimators must be distinct real estimators (the oracle with random errors is the "
                              f"run without estimators), got {list(self.estimators)!r}")
        extra = sorted(set(self.estimator_options) - set(self.estimators))
        if extra:
            raise ConfigError(f"estimator_options name estimators not in the run: {extra!r}; estimators: "
                              f"{list(self.estimators)!r}")

    def record(self) -> dict:
        """The fields as plain values (``estimators`` and ``estimator_options`` only when set, so the
        records of oracle runs stay as they were)."""
        later = {"estimators": (), "estimator_options": {}}
        return {**{k: v for k, v in self.__dict__.items() if k != "setup" and (k not in later or v != later[k])},
                "setup": self.setup.record()}


@dataclass
class CalibrationResult:
    """Episode rows, one row per metric (:data:`CALIBRATION_COLUMNS`), the BOP-threshold rows and timing."""

    episodes: list[dict]
    metrics: list[dict]
    thresholds: list[dict]
    summary: dict
    per_estimator: list[dict] = field(default_factory=list)  # :data:`ESTIMATOR_COLUMNS`, runs of estimators


def _estimator_units(cfg: CalibrationConfig, objs: list) -> list[OracleUnit]:
    """Per estimator, object and episode ``j``: the scene of the oracle run's episode ``j`` (same env seed)."""
    units = []
    for name in cfg.estimators:
        opts = tuple(sorted(cfg.estimator_options.get(name, {}).items()))
        for o in objs:
            for j in range(cfg.episodes_per_object):
                units.append(OracleUnit(obj_id=int(o.obj_id), seed=episode_seed_of(cfg.seed, int(o.obj_id), j, 1),
                                        options=opts, occlusion=cfg.occlusions[j % len(cfg.occlusions)],
                                        tags=(("object", o.name), ("obj_id", int(o.obj_id)), ("episode", j),
                                              ("diameter_m", float(o.diameter))), estimator=name))
    return units


def _mark_misses(rows: list[dict]) -> None:
    """Give the episodes in which an estimator gave no usable estimate an infinite error (see the module doc)."""
    for r in rows:
        if r["reason"] in MISS_REASONS:
            r.update({k: float("inf") for k in _ERROR_FIELDS if k in r or k != "vsd"})


def _units(cfg: CalibrationConfig, objs: list) -> list[OracleUnit]:
    units = []
    for o in objs:
        for j in range(cfg.episodes_per_object):
            rng = child_rng(cfg.seed, int(o.obj_id), j, 1)
            t_mm, r_deg = float(rng.uniform(0, cfg.max_trans_mm)), float(rng.uniform(0, cfg.max_rot_deg))
            occ = cfg.occlusions[j % len(cfg.occlusions)]
            opts = (("seed", cfg.seed), ("trans_noise_mm", t_mm), ("rot_noise_deg", r_deg),
                    ("rot_noise_mode", "fixed"))
            units.append(OracleUnit(obj_id=int(o.obj_id), seed=episode_seed_of(cfg.seed, int(o.obj_id), j, 1),
                                    options=opts, occlusion=occ,
                                    tags=(("object", o.name), ("obj_id", int(o.obj_id)), ("episode", j),
                                          ("trans_mm", t_mm), ("rot_deg", r_deg),
                                          ("diameter_m", float(o.diameter)))))
    return units


def metric_values(rows: list[dict], metrics: tuple[_Metric, ...] = METRICS) -> dict[str, np.ndarray]:
    """Per metric of ``metrics``, its error in every row: NaN where the episode had no estimate, except that a
    real estimator's row (with an ``estimator``) keeps an infinite error (a miss)."""
    out = {}
    for m in metrics:
        vals = []
        for r in rows:
            try:
                v = float(m.value(r))
            except (TypeError, ValueError, ZeroDivisionError, KeyError):
                v = float("nan")
            keep = math.isfinite(v) or (v == math.inf and bool(r.get("estimator")))
            vals.append(v if keep else float("nan"))
        out[m.key] = np.asarray(vals, dtype=np.float64)
    return out


def _threshold_at_level(e: np.ndarray, s: np.ndarray, level: float) -> float | None:
    """The largest observed error ``t`` such that the episodes with error ``<= t`` succeed >= ``level``."""
    best = None
    for t in np.unique(e[np.isfinite(e)]):
        k, n = success_below(e, s, float(t))
        if n and k / n >= level:
            best = float(t)
    return best


def calibrate_rows(rows: list[dict], *, resamples: int = 1000, seed: int = 0, level: float = TOLERANCE_LEVEL,
                   metrics: tuple[_Metric, ...] = METRICS) -> tuple[list[dict], list[dict]]:
    """The calibration table (:data:`CALIBRATION_COLUMNS`) and the BOP-threshold table
    (:data:`THRESHOLD_COLUMNS`) of episode rows holding ``success``, ``add_s``, ``mssd``, ``mspd``,
    ``re_sym_deg``, ``te`` and ``diameter_m`` (and ``vsd``, ``vsd_taus`` for :data:`VSD_METRICS`)."""
    s = np.asarray([bool(r["success"]) for r in rows])
    values = metric_values(rows, metrics)
    table, bop = [], []
    for m in metrics:
        e = values[m.key]
        lo, hi = bootstrap_auc_interval(e, s, resamples=resamples, seed=seed)
        th = best_threshold(e, s)
        keep = ~np.isnan(e)
        table.append({"metric": m.key, "label": m.label, "unit": m.unit, "episodes": int(keep.sum()),
                      "successes": int(s[keep].sum()), "auc": roc_auc(e, s), "auc_lo": lo, "auc_hi": hi,
                      "best_threshold": th.threshold, "youden": th.youden, "tpr": th.tpr, "fpr": th.fpr,
                      "threshold_90": _threshold_at_level(e, s, level)})
        for t in m.bop:
            k, n = success_below(e, s, t - 1e-12)  # BOP's test is strict: error < threshold
            ci = wilson_interval(k, n)
            bop.append({"metric": m.key, "threshold": t, "correct": n, "successes": k,
                        "success_rate": k / n if n else float("nan"), "ci95_lo": ci[0], "ci95_hi": ci[1]})
    return table, bop


def estimator_table(rows: list[dict], metrics: tuple[_Metric, ...] = METRICS) -> list[dict]:
    """Per metric and estimator of the pooled ``rows`` (:data:`ESTIMATOR_COLUMNS`): the episodes with a value
    of the metric, their successes with a 95 % Wilson interval, and the AUC within that estimator alone."""
    names = list(dict.fromkeys(str(r["estimator"]) for r in rows))
    s = np.asarray([bool(r["success"]) for r in rows])
    est = np.asarray([str(r["estimator"]) for r in rows])
    values = metric_values(rows, metrics)
    out = []
    for m in metrics:
        for name in names:
            pick = (est == name) & ~np.isnan(values[m.key])
            k, n = int(s[pick].sum()), int(pick.sum())
            ci = wilson_interval(k, n)
            out.append({"metric": m.key, "estimator": name, "episodes": n, "successes": k,
                        "success_rate": k / n if n else float("nan"), "ci95_lo": ci[0], "ci95_hi": ci[1],
                        "auc": roc_auc(values[m.key][est == name], s[est == name])})
    return out


def _estimator_summary(rows: list[dict]) -> dict:
    """Per estimator: episodes, successes (95 % Wilson interval) and misses."""
    out = {}
    for name in dict.fromkeys(str(r["estimator"]) for r in rows):
        mine = [r for r in rows if r["estimator"] == name]
        k = sum(bool(r["success"]) for r in mine)
        lo, hi = wilson_interval(k, len(mine))
        out[name] = {"episodes": len(mine), "successes": k, "success_rate": k / len(mine), "ci95_lo": lo,
                     "ci95_hi": hi, "misses": sum(r["reason"] in MISS_REASONS for r in mine)}
    return out


def run_calibration(cfg: CalibrationConfig, *, progress: bool = True) -> CalibrationResult:
    """Run the episodes (see the module doc) and calibrate every metric of :data:`METRICS`.

    Raises:
        ConfigError: A bad field of ``cfg`` or an object that is not a graspable object of the set.
        BackendError: Episodes lost with their workers beyond the retries.
    """
    cfg.check()
    real = bool(cfg.estimators)
    setup = EpisodeSetup(**{**cfg.setup.__dict__, "mspd": True, "vsd": cfg.setup.vsd or real})
    cfg = CalibrationConfig(**{**cfg.__dict__, "setup": setup})
    objs = check_objects(setup, cfg.targets)
    units = _estimator_units(cfg, objs) if real else _units(cfg, objs)
    stats = RunStats()
    t0 = time.perf_counter()
    rows = list(run_oracle_units(setup, units, progress=progress, desc="calibration", stats=stats))
    wall = time.perf_counter() - t0
    order = {name: i for i, name in enumerate(cfg.estimators)}
    rows.sort(key=lambda r: (order.get(r.get("estimator"), -1), r["obj_id"], r["episode"]))
    metrics = METRICS + VSD_METRICS if setup.vsd else METRICS
    if real:
        _mark_misses(rows)
    table, bop = calibrate_rows(rows, resamples=cfg.resamples, seed=cfg.seed, level=cfg.level, metrics=metrics)
    summary = {"config": cfg.record(), "episodes": len(rows), "successes": sum(bool(r["success"]) for r in rows),
               "wall_s": wall, "episodes_per_s": len(rows) / wall if wall > 0 else None,
               "run": stats.record(setup.workers)}
    if real:
        summary["estimators"] = _estimator_summary(rows)
    per_estimator = estimator_table(rows, metrics) if real else []
    return CalibrationResult(rows, table, bop, summary, per_estimator)


def write_calibration(result: CalibrationResult, out: str | Path) -> dict[str, Path]:
    """Write ``calibration.csv``, ``calibration_thresholds.csv``, ``calibration_episodes.csv`` and
    ``calibration.json`` into ``out`` (made if absent); for a run of real estimators also
    ``calibration_estimators.csv``."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    paths = {"table": out / "calibration.csv", "thresholds": out / "calibration_thresholds.csv",
             "episodes": out / "calibration_episodes.csv", "json": out / "calibration.json"}
    write_csv(paths["table"], result.metrics, CALIBRATION_COLUMNS)
    write_csv(paths["thresholds"], result.thresholds, THRESHOLD_COLUMNS)
    real = "estimators" in result.summary
    write_csv(paths["episodes"], result.episodes, ESTIMATOR_EPISODE_COLUMNS if real else EPISODE_COLUMNS)
    extra = {}
    if real:
        paths["estimators"] = out / "calibration_estimators.csv"
        write_csv(paths["estimators"], result.per_estimator, ESTIMATOR_COLUMNS)
        extra = {"per_estimator": result.per_estimator}
    atomic_write_json(paths["json"], jsonable({**result.summary, "metrics": result.metrics,
                                              "bop_thresholds": result.thresholds, **extra}))
    return paths
