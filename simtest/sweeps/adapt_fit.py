"""The fitted sampler of ``simtest adapt``: where an estimator fails, by factor, turned into generation weights.

Each factor of :class:`~simtest.sweeps.adapt_targets.TargetResult` is binned (the ranges the generation config
draws from split into equal parts, categories as they are), and every bin gets its failure rate with a 95 %
Wilson interval (:func:`simtest.metrics.intervals.wilson_interval`). **The rule**: a bin's adapted mass is

    mass = floor / B + (1 - floor) * low / sum(low)

where ``B`` is the factor's number of bins and ``low`` the lower end of the bin's failure-rate interval. The
lower end, not the rate, so that a bin with few targets (a wide interval) is not chased on noise; the floor (a
share of the uniform mass, default 0.25) so that no bin gets nothing; when no bin's lower end is above 0 the mass
stays uniform. The masses become weights of the generation config's parts (:data:`FACTORS`); conditions (image
corruptions, depth noise) are fitted and reported too but no generation parameter draws them.

Pure functions: no files are read or written here (:mod:`simtest.sweeps.adapt_targets` reads the sweep,
:mod:`simtest.sweeps.adapt` writes the outputs).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass

import numpy as np

from simtest.errors import ConfigError
from simtest.metrics.intervals import wilson_interval
from simtest.sweeps.adapt_targets import TargetResult

__all__ = ["Factor", "FACTORS", "BinFit", "FactorFit", "adapted_mass", "fit_factor", "fit_sampler",
           "adapted_config", "uniform_config", "DEFAULT_FLOOR", "DEFAULT_BINS"]

DEFAULT_FLOOR = 0.25
DEFAULT_BINS = 4


@dataclass(frozen=True)
class Factor:
    """One factor: the :class:`TargetResult` attribute it bins, its unit, the generation-config range its bins
    split (dotted path; None for categories) and the config field its weights go to (None: not generated)."""

    name: str
    attr: str
    unit: str
    span: str | None
    weights: str | None


#: The factors fitted, in report order.
FACTORS: tuple[Factor, ...] = (
    Factor("condition", "condition", "", None, None),
    Factor("object", "obj_id", "obj_id", None, "scene.object_weights"),
    Factor("visibility", "visib_fract", "visible fraction", "occlusion.visib_band", "occlusion.visib_weights"),
    Factor("distance", "distance_m", "m", "shell.distance", "shell.distance_weights"),
    Factor("elevation", "elevation_deg", "deg", "shell.elevation_deg", "shell.elevation_weights"),
    Factor("inplane", "inplane_deg", "deg", "shell.roll_range_deg", "shell.roll_weights"),
)


@dataclass(frozen=True)
class BinFit:
    """One bin: its label, range ``[lo, hi)`` (None for a category), targets ``n``, failures, failure rate and
    its 95 % Wilson interval, the uniform mass ``1 / B`` and the adapted mass."""

    label: str
    lo: float | None
    hi: float | None
    n: int
    failures: int
    rate: float
    ci_low: float
    ci_high: float
    uniform: float
    mass: float


@dataclass(frozen=True)
class FactorFit:
    """The bins of one factor (masses sum to 1) and the span they split (None for categories)."""

    factor: Factor
    span: tuple[float, float] | None
    bins: tuple[BinFit, ...]

    def to_dict(self) -> dict:
        return {"factor": self.factor.name, "unit": self.factor.unit, "weights": self.factor.weights,
                "span": None if self.span is None else list(self.span), "bins": [asdict(b) for b in self.bins]}


def adapted_mass(failures: Sequence[int], totals: Sequence[int], floor: float = DEFAULT_FLOOR) -> np.ndarray:
    """The adapted mass of each bin (sums to 1) from its failures and targets: the module's rule.

    Raises:
        ValueError: No bins, ``floor`` outside (0, 1], or counts of different lengths or out of range.
    """
    if not 0.0 < floor <= 1.0:
        raise ValueError(f"floor must be in (0, 1], got {floor!r}")
    if len(failures) != len(totals) or not len(totals):
        raise ValueError(f"need as many failure counts as totals (at least one), got {len(failures)} and "
                         f"{len(totals)}")
    low = np.array([wilson_interval(int(k), int(n))[0] for k, n in zip(failures, totals)], np.float64)
    b = len(totals)
    if low.sum() <= 0.0:
        return np.full(b, 1.0 / b)
    return floor / b + (1.0 - floor) * low / low.sum()


def _label(lo: float, hi: float) -> str:
    return f"{lo:.3g}-{hi:.3g}"


def fit_factor(factor: Factor, values: Sequence, failed: Sequence[bool], span: tuple[float, float] | None = None,
               bins: int = DEFAULT_BINS, floor: float = DEFAULT_FLOOR) -> FactorFit:
    """Bin ``values`` (one per target; ``failed`` alike) and fit the masses.

    Args:
        factor: What is binned.
        values: The targets' values: numbers split over ``span`` into ``bins`` equal parts (values outside fall
            into the end parts), or categories (``span`` None), one bin per distinct value in sorted order.
        failed: Whether each target failed.
        span: ``(lo, hi)`` range of a numeric factor, in its unit.
        bins: Parts of ``span``.
        floor: The rule's floor.

    Raises:
        ValueError: ``values`` and ``failed`` of different lengths, no values, ``bins < 1`` or an empty span.
    """
    if len(values) != len(failed) or not len(values):
        raise ValueError(f"need one failure flag per value (at least one), got {len(values)} and {len(failed)}")
    fail = np.asarray(failed, bool)
    if span is None:
        cats = sorted(set(values), key=lambda v: (str(type(v)), v))
        idx = np.array([cats.index(v) for v in values])
        edges: list[tuple[float | None, float | None, str]] = [(None, None, str(c)) for c in cats]
    else:
        lo, hi = float(span[0]), float(span[1])
        if bins < 1 or not hi > lo:
            raise ValueError(f"{factor.name}: need bins >= 1 and a span with hi > lo, got {bins!r} and {span!r}")
        step = (hi - lo) / bins
        idx = np.clip(np.floor((np.asarray(values, np.float64) - lo) / step), 0, bins - 1).astype(int)
        edges = [(lo + k * step, lo + (k + 1) * step, _label(lo + k * step, lo + (k + 1) * step))
                 for k in range(bins)]
    totals = np.bincount(idx, minlength=len(edges))
    fails = np.bincount(idx, weights=fail.astype(float), minlength=len(edges)).astype(int)
    mass = adapted_mass(fails, totals, floor)
    out = []
    for k, (a, b, label) in enumerate(edges):
        ci = wilson_interval(int(fails[k]), int(totals[k]))
        rate = fails[k] / totals[k] if totals[k] else math.nan
        out.append(BinFit(label, a, b, int(totals[k]), int(fails[k]), float(rate), ci[0], ci[1], 1.0 / len(edges),
                          float(mass[k])))
    return FactorFit(factor, None if span is None else (float(span[0]), float(span[1])), tuple(out))


def _get(cfg, dotted: str):
    node = cfg
    for part in dotted.split("."):
        node = getattr(node, part)
    return node


def _span(cfg, factor: Factor) -> tuple[float, float] | None:
    if factor.span is None:
        return None
    if factor.name == "visibility":
        return (0.0, 1.0)
    if factor.name == "inplane":
        return cfg.shell.roll_range()
    return tuple(_get(cfg, factor.span))


def fit_sampler(targets: Sequence[TargetResult], base, bins: int = DEFAULT_BINS, floor: float = DEFAULT_FLOOR
                ) -> list[FactorFit]:
    """Every factor of :data:`FACTORS` fitted on ``targets``, the numeric ones over the ranges of ``base`` (a
    :class:`~simtest.generators.config.GenerateConfig`; visibility over [0, 1]).

    Raises:
        ConfigError: No targets, or ``base`` not a shell-rig config (the other rigs draw their views otherwise).
    """
    if not targets:
        raise ConfigError("no targets to fit: the sweep has no finished pose cell of this estimator")
    if base.rig != "shell":
        raise ConfigError(f"simtest adapt aims the shell rig's views; the sweep's config has rig = {base.rig!r}")
    failed = [t.failed for t in targets]
    return [fit_factor(f, [getattr(t, f.attr) for t in targets], failed, _span(base, f), bins, floor)
            for f in FACTORS]


def _rounded(mass: Sequence[float]) -> list[float]:
    return [round(float(m), 4) for m in mass]


def adapted_config(base, fits: Sequence[FactorFit], images: int, seed: int):
    """``base`` with the fitted weights, ``images`` images (``scenes`` rounded up over ``frames_per_scene``)
    and ``seed``: the adapted generation config. Factors without a generation field are left out."""
    over: dict = {"scenes": max(1, math.ceil(images / base.frames_per_scene)), "seed": int(seed)}
    for fit in fits:
        f = fit.factor
        if f.weights is None:
            continue
        if f.name == "object":
            over[f.weights] = {b.label: round(b.mass * len(fit.bins), 4) for b in fit.bins}
            continue
        if f.name == "visibility":
            over["occlusion.level"] = None
            over[f.span] = list(fit.span)
        if f.name == "inplane":
            over[f.span] = list(fit.span)
        over[f.weights] = _rounded(b.mass for b in fit.bins)
    return base.replace(**over)


def uniform_config(base, images: int, seed: int):
    """The control: ``base`` with the same ``images`` and ``seed`` as :func:`adapted_config` and no weights."""
    return base.replace(scenes=max(1, math.ceil(images / base.frames_per_scene)), seed=int(seed))
