"""The sweep report's plots (matplotlib, Agg), each returned as a :class:`Plot` holding a base64 PNG.

* **Metric per condition**: a bar per estimator and condition with its 95 % interval as an error bar and the
  target count under each condition; a score of exactly 0 is drawn as a thick line on the axis with a ``0``
  label (a missing score as ``n/a``), so neither looks like the other; the legend sits outside the axes. With
  several severities, lines over severity instead (error bars, offset sideways).
* **Grasp success vs occlusion level**: one line per estimator with Wilson intervals; the lines are offset
  sideways and differ in marker and line style, so estimators with the same rates stay visible.
* **Pose error vs grasp outcome**: the episodes, and a logistic success curve drawn only over the range of the
  errors seen, with a 95 % band (bootstrap over episodes). Its 50 % point is stated only when it lies inside
  that range and both outcomes have at least :data:`MIN_OUTCOMES` episodes; otherwise the plot says why not.
"""

from __future__ import annotations

import base64
import io
import math
import textwrap
from dataclasses import dataclass

import numpy as np

from simtest.metrics.registry import metric
from simtest.sweeps.cells import Scores

__all__ = ["Plot", "metric_plot", "grasp_occlusion_plot", "error_vs_grasp_plot", "fit_logistic",
           "logistic_band", "fifty_percent_note", "column_label", "MIN_OUTCOMES", "MARKERS", "LINESTYLES"]

#: Fewest successes and failures for the fitted curve's 50 % point to be stated.
MIN_OUTCOMES = 5
#: Marker and line style cycles of line plots (estimator k gets entry k modulo the length).
MARKERS = ("o", "s", "^", "D", "v", "P", "X", "*")
LINESTYLES = ("-", "--", ":", "-.")
_BAND_RESAMPLES = 400
_NEVER = 1e12  # stands for the 50 % point of a curve that does not fall (mm)
_LEGEND = {"loc": "upper left", "bbox_to_anchor": (1.01, 1.0), "fontsize": 7, "frameon": False,
           "title_fontsize": 7}


@dataclass(frozen=True)
class Plot:
    """One figure of the report: its element id, title, a caption note (may be empty) and PNG bytes in base64."""

    id: str
    title: str
    note: str
    png_b64: str


def column_label(c) -> str:
    """The table column (and tick label) of a condition: ``L0`` for clean, a depth preset or sensor by its
    name, the others by the condition name."""
    if c.factor == "clean":
        return "L0"
    if c.factor in ("depth", "sensor"):
        return c.level
    return c.name


def _png(fig) -> str:
    import matplotlib.pyplot as plt

    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _common_n(scores: Scores, names: list[str], cond: str, kind: str, key: str) -> int | None:
    """The count shared by every estimator's score of ``cond`` (None when they differ or none has one)."""
    ns = {scores.get(e, cond, kind, key)[1].n for e in names} - {0}
    return ns.pop() if len(ns) == 1 else None


def _yerr(v: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Error bar lengths below and above ``v`` (0 where the interval is unknown or infinite)."""
    below = np.where(np.isfinite(lo), v - lo, 0.0)
    above = np.where(np.isfinite(hi), hi - v, 0.0)
    return np.nan_to_num(np.clip(np.stack([below, above]), 0.0, None))


def metric_plot(cfg, conds, scores: Scores, key: str) -> Plot:
    """The plot of one metric over the conditions (bars, or lines over severity when several were swept)."""
    plt = _pyplot()
    spec = metric(key)
    names = [e.name for e in cfg.estimators]
    severities = sorted({c.severity for c in conds if c.severity is not None})
    fig, ax = plt.subplots(figsize=(max(6.4, 2.4 + 0.6 * len(conds)), 3.3))
    if len(severities) > 1:
        _severity_lines(ax, conds, scores, names, key, severities)
        title = f"{spec.label} vs corruption severity"
    else:
        _bars(ax, conds, scores, names, key)
        title = f"{spec.label} per condition"
    methods = sorted({scores.get(e, c.name, "pose", key)[1].method for e in names for c in conds} - {""})
    ax.set_ylabel(f"{spec.label} ({spec.unit})")
    named = [{"wilson": "Wilson"}.get(m, m) for m in methods]
    ax.set_title(title + (f" ({' / '.join(named)} 95 % intervals)" if named else ""), fontsize=9)
    ax.grid(alpha=0.3, axis="y")
    ax.legend(**_LEGEND)
    note = "" if methods else "no intervals for this score"
    return Plot(f"plot-{key}", title, note, _png(fig))


def _bars(ax, conds, scores: Scores, names: list[str], key: str) -> None:
    spec = metric(key)
    width = 0.8 / max(1, len(names))
    x0 = np.arange(len(conds))
    top = 0.0
    for k, name in enumerate(names):
        got = [scores.get(name, c.name, "pose", key) for c in conds]
        v = np.array([g[0] for g in got]) * spec.scale
        lo = np.array([g[1].low for g in got]) * spec.scale
        hi = np.array([g[1].high for g in got]) * spec.scale
        x = x0 + k * width
        bars = ax.bar(x, np.nan_to_num(v), width, label=name, zorder=2)
        colour = bars.patches[0].get_facecolor()
        ax.errorbar(x, v, yerr=_yerr(v, lo, hi), fmt="none", ecolor="#333", elinewidth=0.9,
                    capsize=2, zorder=3)
        top = max([top, *v[np.isfinite(v)], *hi[np.isfinite(hi)]])
        for xi, vi in zip(x, v):
            if math.isnan(vi):
                ax.text(xi, 0.05, "n/a", ha="center", va="bottom", fontsize=6, color="#777", rotation=90,
                        transform=ax.get_xaxis_transform())
            elif vi == 0:  # a zero score: a thick mark on the axis and its value, not an empty slot
                ax.hlines(0, xi - width * 0.45, xi + width * 0.45, colors=[colour], linewidth=3, zorder=4)
                ax.text(xi, 0.05, "0", ha="center", va="bottom", fontsize=8, color="#222", zorder=5,
                        transform=ax.get_xaxis_transform(), bbox={"facecolor": "white", "edgecolor": "none",
                                                                 "pad": 0.3})
    top = top or 1.0
    ax.set_ylim(-0.03 * top, top * 1.08)
    ns = [_common_n(scores, names, c.name, "pose", key) for c in conds]
    ax.set_xticks(x0 + width * (len(names) - 1) / 2)
    many = len(conds) > 6
    ax.set_xticklabels([column_label(c) + (f"\nn={n}" if n else "") for c, n in zip(conds, ns)], fontsize=7,
                       rotation=30 if many else 0, ha="right" if many else "center")


def _severity_lines(ax, conds, scores: Scores, names: list[str], key: str, severities: list[int]) -> None:
    spec = metric(key)
    corruptions = sorted({c.level for c in conds if c.factor == "corruption"})
    series = [(name, corr) for name in names for corr in corruptions]
    for k, (name, corr) in enumerate(series):
        got = [scores.get(name, "clean", "pose", key)] + [scores.get(name, f"{corr}-{s}", "pose", key)
                                                          for s in severities]
        v = np.array([g[0] for g in got]) * spec.scale
        lo = np.array([g[1].low for g in got]) * spec.scale
        hi = np.array([g[1].high for g in got]) * spec.scale
        dx = (k - (len(series) - 1) / 2) * 0.06
        ax.errorbar(np.array([0, *severities]) + dx, v, yerr=_yerr(v, lo, hi), marker=MARKERS[k % len(MARKERS)],
                    ls=LINESTYLES[k % len(LINESTYLES)], capsize=2, ms=4, label=f"{name}: {corr}")
    ns = {scores.get(name, c.name, "pose", key)[1].n for name in names for c in conds
          if c.factor in ("clean", "corruption")} - {0}
    counts = f"n={ns.pop()} targets per point; " if len(ns) == 1 else "n differs between points (tables); "
    ax.set_xlabel(f"severity (0 = clean); {counts}lines offset sideways so equal values stay visible", fontsize=7)


def grasp_occlusion_plot(cfg, conds, scores: Scores) -> Plot:
    """Grasp success per occlusion level, one offset line per estimator with Wilson intervals."""
    plt = _pyplot()
    occ = [c for c in conds if c.factor in ("clean", "occlusion")]
    names = [e.name for e in cfg.estimators]
    fig, ax = plt.subplots(figsize=(6.4, 3.3))
    for k, name in enumerate(names):
        got = [scores.get(name, c.name, "grasp", "success_rate") for c in occ]
        v = np.array([g[0] for g in got]) * 100
        lo = np.array([g[1].low for g in got]) * 100
        hi = np.array([g[1].high for g in got]) * 100
        dx = (k - (len(names) - 1) / 2) * min(0.08, 0.4 / max(1, len(names)))
        ax.errorbar(np.arange(len(occ)) + dx, v, yerr=_yerr(v, lo, hi), marker=MARKERS[k % len(MARKERS)],
                    ls=LINESTYLES[k % len(LINESTYLES)], capsize=3, ms=5, label=name)
    ns = [_common_n(scores, names, c.name, "grasp", "success_rate") for c in occ]
    ax.set_xticks(range(len(occ)))
    ax.set_xticklabels([column_label(c) + (f"\nn={n}" if n else "") for c, n in zip(occ, ns)], fontsize=7)
    ax.set_ylim(-5, 105)
    ax.set_ylabel("grasp success (%)")
    ax.set_xlabel("occlusion level (physical occluders in the grasp scene)", fontsize=7)
    ax.set_title("Grasp success vs occlusion (95 % Wilson intervals)", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(title="lines offset sideways:\nequal rates stay visible", **_LEGEND)
    return Plot("plot-grasp-occlusion", "Grasp success vs occlusion level",
                "lines are offset sideways and differ in marker and style, so estimators with equal rates "
                "stay visible", _png(fig))


def fit_logistic(x: np.ndarray, y: np.ndarray, iterations: int = 50) -> tuple[float, float]:
    """Maximum-likelihood logistic fit ``P(y=1) = 1 / (1 + exp(-(a + b x)))`` by Newton's method (with a small
    ridge so separable data stays finite). Returns ``(a, b)``."""
    x = np.asarray(x, dtype=np.float64)
    y = np.asarray(y, dtype=np.float64)
    X = np.stack([np.ones_like(x), x], axis=1)
    w = np.zeros(2)
    for _ in range(iterations):
        p = 1.0 / (1.0 + np.exp(-np.clip(X @ w, -30, 30)))
        g = X.T @ (y - p) - 1e-3 * w
        H = -(X.T * (p * (1 - p))) @ X - 1e-3 * np.eye(2)
        step = np.linalg.solve(H, g)
        w -= step
        if np.abs(step).max() < 1e-8:
            break
    return float(w[0]), float(w[1])


def _logistic(a: float, b: float, xs: np.ndarray) -> np.ndarray:
    return 1.0 / (1.0 + np.exp(-np.clip(a + b * xs, -30, 30)))


def logistic_band(x: np.ndarray, y: np.ndarray, xs: np.ndarray, *, seed: int = 0,
                  resamples: int = _BAND_RESAMPLES) -> tuple[np.ndarray, np.ndarray, tuple[float, float]]:
    """Bootstrap over the episodes of the fitted logistic curve: its pointwise 95 % band at ``xs`` and the 95 %
    interval of its 50 % point (``inf`` for resamples whose curve does not fall; resamples with a single
    outcome are skipped). Returns ``(low, high, (x50 low, x50 high))``."""
    rng = np.random.default_rng(seed)
    curves, x50 = [], []
    for _ in range(resamples):
        idx = rng.integers(0, len(x), len(x))
        if 0 < y[idx].sum() < len(idx):
            a, b = fit_logistic(x[idx], y[idx])
            curves.append(_logistic(a, b, xs))
            x50.append(-a / b if b < 0 else math.inf)
    if not curves:
        return np.zeros_like(xs), np.ones_like(xs), (-math.inf, math.inf)
    lo, hi = np.percentile(np.array(curves), [2.5, 97.5], axis=0)
    q = np.percentile(np.minimum(np.array(x50), _NEVER), [2.5, 97.5])  # inf - inf would be NaN
    return lo, hi, tuple(math.inf if v >= _NEVER else float(v) for v in q)


def fifty_percent_note(a: float, b: float, x: np.ndarray, y: np.ndarray,
                       x50_interval: tuple[float, float]) -> str:
    """What may be said of the fitted curve's 50 % point: ``50 % at X mm [low, high]`` only when both outcomes
    have at least :data:`MIN_OUTCOMES` episodes and the point and its 95 % interval lie within the errors
    seen."""
    failures, successes = int((y == 0).sum()), int((y == 1).sum())
    if min(failures, successes) < MIN_OUTCOMES:
        return (f"50 % point not estimated: {failures} failure(s) and {successes} success(es) "
                f"(fewer than {MIN_OUTCOMES} of one outcome)")
    span = f"{x.min():.1f}-{x.max():.1f} mm"
    x50 = -a / b if b < 0 else math.inf
    if not x.min() <= x50 <= x.max():
        return f"50 % not reached within the data ({span})"
    lo, hi = x50_interval
    if not (x.min() <= lo and hi <= x.max()):
        return f"50 % point not pinned down within the data: its 95 % interval reaches beyond {span}"
    return f"50 % at {x50:.1f} mm [{lo:.1f}, {hi:.1f}]"


def error_vs_grasp_plot(results: list[dict]) -> Plot:
    """Grasp outcome against the ADD(-S) of the estimate used, with the fitted curve over the data's range."""
    plt = _pyplot()
    eps = []
    for r in results:
        try:
            err = float(r["add_s_or_add_m"])
        except (TypeError, ValueError):
            continue
        if r["kind"] == "grasp" and math.isfinite(err):
            eps.append((err * 1000, 1.0 if str(r["success"]).lower() in ("true", "1") else 0.0))
    fig, ax = plt.subplots(figsize=(6.4, 3.3))
    note = "no episode with a finite pose error"
    if eps:
        x, y = np.array([e[0] for e in eps]), np.array([e[1] for e in eps])
        jitter = np.random.default_rng(0).uniform(-0.04, 0.04, len(y))
        ax.scatter(x, y + jitter, s=14, alpha=0.6, c=np.where(y > 0, "tab:green", "tab:red"), zorder=3)
        if 0 < y.sum() < len(y):
            a, b = fit_logistic(x, y)
            xs = np.linspace(x.min(), x.max(), 200)  # only over the errors seen
            lo, hi, x50 = logistic_band(x, y, xs)
            ax.fill_between(xs, lo, hi, color="gray", alpha=0.25, lw=0, label="95 % band (bootstrap)")
            note = fifty_percent_note(a, b, x, y, x50)
            ax.plot(xs, _logistic(a, b, xs), "k-", label="logistic fit:\n" + textwrap.fill(note, 34))
            if note.startswith("50 % at"):
                ax.axvline(-a / b, color="gray", ls="--")
            ax.legend(**_LEGEND)
        else:
            note = f"no fit: all {len(y)} episodes {'succeeded' if y.all() else 'failed'}"
    ax.set_xlabel("ADD(-S) of the estimate used (mm)")
    ax.set_ylabel("grasp success")
    ax.set_yticks([0, 1])
    ax.set_yticklabels(["fail", "success"])
    ax.set_title("Pose error vs grasp outcome", fontsize=9)
    ax.grid(alpha=0.3)
    return Plot("plot-error-vs-grasp", "Pose error vs grasp outcome", note, _png(fig))
