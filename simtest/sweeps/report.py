"""Sweep outputs: tidy ``results.csv``, ``summary.csv``, Markdown tables in the classic robustness layout, and
one self-contained ``report.html`` (tables, plots and example images embedded as base64 PNG/JPEG).

Plots: metric per condition for each estimator (lines over severity when several severities were swept),
grasp success vs occlusion level with 95 % Wilson intervals, pose error vs grasp outcome with a fitted
logistic success curve, and one example picture per condition (:mod:`simtest.sweeps.examples`: RGB, or the
colourized depth map for depth-noise and depth-sensor conditions).

Table columns, in groups: occlusion (``L0`` = clean, ``L1``..``L3``), corruptions, depth (image-space presets,
then simulated sensors, each by its preset name), renderer (render conditions by name). Generation conditions
(depth sensors, renderers) have pose cells only, so the grasp table leaves them out.
"""

from __future__ import annotations

import base64
import html
import io
import json
import math
from pathlib import Path
from typing import Any

import numpy as np

from simtest.sweeps.cells import RESULTS_FILE, SUMMARY_FILE
from simtest.io.files import atomic_write_text, read_csv
from simtest.metrics.registry import metric

__all__ = ["write_report", "fit_logistic", "markdown_tables"]

def _f(v: Any) -> float:
    try:
        x = float(v)
    except (TypeError, ValueError):
        return float("nan")
    return x


def _value(summary: list[dict], est: str, cond: str, kind: str, metric: str) -> float:
    for r in summary:
        if r["estimator"] == est and r["condition"] == cond and r["kind"] == kind and r["metric"] == metric:
            return _f(r["value"])
    return float("nan")


def _groups(conds) -> list[tuple[str, list]]:
    groups = [("", [c for c in conds if c.factor in ("clean", "occlusion")]),
              ("corruption", [c for c in conds if c.factor == "corruption"]),
              ("depth", [c for c in conds if c.factor in ("depth", "sensor")]),
              ("renderer", [c for c in conds if c.factor == "render"])]
    return [(g, cs) for g, cs in groups if cs]


def _column_label(c) -> str:
    if c.factor == "clean":
        return "L0"
    if c.factor in ("depth", "sensor"):
        return c.level
    return c.name


def _header(cols) -> str:
    return ("| estimator | " + " | ".join(_column_label(c) for c in cols) + " |\n|---|" +
            "|".join("---:" for _ in cols) + "|")


def markdown_tables(cfg, conds, summary: list[dict]) -> str:
    """One table per metric: rows estimators, columns L0 L1 L2 L3 | corruptions | depth presets."""
    cols = [c for _, cs in _groups(conds) for c in cs]
    header = _header(cols)
    parts = []
    for m in cfg.metrics:
        spec = metric(m)
        rows = [f"| {e.name} | " + " | ".join(_fmt(spec.shown(_value(summary, e.name, c.name, "pose", m)))
                                                for c in cols) + " |" for e in cfg.estimators]
        parts.append(f"### {spec.label} ({spec.unit})\n\n{header}\n" + "\n".join(rows))
    if cfg.grasp.episodes > 0:
        rows = []
        grasp_cols = [c for c in cols if c.factor not in ("sensor", "render")]
        for e in cfg.estimators:
            cells = []
            for c in grasp_cols:
                v = _value(summary, e.name, c.name, "grasp", "success_rate")
                lo = _value(summary, e.name, c.name, "grasp", "ci95_low")
                hi = _value(summary, e.name, c.name, "grasp", "ci95_high")
                cells.append("-" if math.isnan(v) else f"{v * 100:.0f} [{lo * 100:.0f}, {hi * 100:.0f}]")
            rows.append(f"| {e.name} | " + " | ".join(cells) + " |")
        parts.append(f"### Grasp success (%, 95% CI; {cfg.grasp.episodes} episodes per cell; occlusion is "
                     f"physical in the grasp scene)\n\n{_header(grasp_cols)}\n" + "\n".join(rows))
    groups = ", ".join(f"{g or 'occlusion'}: {' '.join(_column_label(c) for c in cs)}" for g, cs in _groups(conds))
    return "## Robustness tables\n\nColumns (" + groups + ").\n\n" + "\n\n".join(parts) + "\n"


def _fmt(v: float) -> str:
    return "-" if v is None or math.isnan(v) else f"{v:.1f}"


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


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90, bbox_inches="tight")
    import matplotlib.pyplot as plt

    plt.close(fig)
    return base64.b64encode(buf.getvalue()).decode("ascii")


def _plots(cfg, conds, summary: list[dict], results: list[dict]) -> list[tuple[str, str, str]]:
    """(id, title, base64 png) of every plot."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plots = []
    severities = sorted({c.severity for c in conds if c.severity is not None})
    corruptions = sorted({c.level for c in conds if c.factor == "corruption"})
    for m in cfg.metrics:
        spec = metric(m)
        label, scale, unit = spec.label, spec.scale, spec.unit
        fig, ax = plt.subplots(figsize=(5.8, 3.2))
        if len(severities) > 1:
            for e in cfg.estimators:
                clean = _value(summary, e.name, "clean", "pose", m) * scale
                for corr in corruptions:
                    ys = [clean] + [_value(summary, e.name, f"{corr}-{s}", "pose", m) * scale for s in severities]
                    ax.plot([0] + severities, ys, marker="o", label=f"{e.name}: {corr}")
            ax.set_xlabel("severity (0 = clean)")
            title = f"{label} vs corruption severity"
        else:
            labels = [_column_label(c) for c in conds]
            width = 0.8 / max(1, len(cfg.estimators))
            for k, e in enumerate(cfg.estimators):
                ys = [_value(summary, e.name, c.name, "pose", m) * scale for c in conds]
                ax.bar(np.arange(len(conds)) + k * width, ys, width, label=e.name)
            ax.set_xticks(np.arange(len(conds)) + width * (len(cfg.estimators) - 1) / 2)
            ax.set_xticklabels(labels, rotation=30, ha="right")
            title = f"{label} per condition"
        ax.set_ylabel(f"{label} ({unit})")
        ax.set_title(title)
        ax.grid(alpha=0.3)
        ax.legend(fontsize=7, ncol=2)
        plots.append((f"plot-{m}", title, _png(fig)))
    if cfg.grasp.episodes > 0:
        occ = [c for c in conds if c.factor in ("clean", "occlusion")]
        fig, ax = plt.subplots(figsize=(5.8, 3.2))
        for e in cfg.estimators:
            v = np.array([_value(summary, e.name, c.name, "grasp", "success_rate") for c in occ]) * 100
            lo = np.array([_value(summary, e.name, c.name, "grasp", "ci95_low") for c in occ]) * 100
            hi = np.array([_value(summary, e.name, c.name, "grasp", "ci95_high") for c in occ]) * 100
            ax.errorbar(range(len(occ)), v, yerr=[v - lo, hi - v], marker="o", capsize=3, label=e.name)
        ax.set_xticks(range(len(occ)))
        ax.set_xticklabels([_column_label(c) for c in occ])
        ax.set_ylim(-5, 105)
        ax.set_ylabel("grasp success (%)")
        ax.set_xlabel("occlusion level")
        ax.set_title("Grasp success vs occlusion (95 % Wilson intervals)")
        ax.grid(alpha=0.3)
        ax.legend(fontsize=8)
        plots.append(("plot-grasp-occlusion", "Grasp success vs occlusion level", _png(fig)))
        eps = [r for r in results if r["kind"] == "grasp" and math.isfinite(_f(r["add_s_or_add_m"]))]
        fig, ax = plt.subplots(figsize=(5.8, 3.2))
        if eps:
            x = np.array([_f(r["add_s_or_add_m"]) * 1000 for r in eps])
            y = np.array([1.0 if str(r["success"]).lower() in ("true", "1") else 0.0 for r in eps])
            jitter = np.random.default_rng(0).uniform(-0.04, 0.04, len(y))
            ax.scatter(x, y + jitter, s=14, alpha=0.6, c=np.where(y > 0, "tab:green", "tab:red"))
            if 0 < y.sum() < len(y):
                a, b = fit_logistic(x, y)
                xs = np.linspace(0, max(x.max(), 1.0), 200)
                ax.plot(xs, 1 / (1 + np.exp(-(a + b * xs))), "k-", label="logistic fit")
                if b < 0:
                    ax.axvline(-a / b, color="gray", ls="--", label=f"50 % at {-a / b:.1f} mm")
                ax.legend(fontsize=8)
        ax.set_xlabel("ADD(-S) of the estimate used (mm)")
        ax.set_ylabel("grasp success")
        ax.set_yticks([0, 1])
        ax.set_yticklabels(["fail", "success"])
        ax.set_title("Pose error vs grasp outcome")
        ax.grid(alpha=0.3)
        plots.append(("plot-error-vs-grasp", "Pose error vs grasp outcome", _png(fig)))
    return plots


def _md_to_html_tables(md: str) -> str:
    """The Markdown tables of :func:`markdown_tables` as HTML."""
    out, rows = [], []

    def flush() -> None:
        if rows:
            head, body = rows[0], rows[2:]
            out.append("<table><thead><tr>" + "".join(f"<th>{html.escape(c)}</th>" for c in head) +
                       "</tr></thead><tbody>" + "".join("<tr>" + "".join(f"<td>{html.escape(c)}</td>" for c in r)
                                                        + "</tr>" for r in body) + "</tbody></table>")
            rows.clear()

    for line in md.splitlines():
        if line.startswith("|"):
            rows.append([c.strip() for c in line.strip("|").split("|")])
            continue
        flush()
        if line.startswith("### "):
            out.append(f"<h3>{html.escape(line[4:])}</h3>")
        elif line.startswith("## "):
            out.append(f"<h2>{html.escape(line[3:])}</h2>")
        elif line.strip():
            out.append(f"<p>{html.escape(line)}</p>")
    flush()
    return "\n".join(out)


def _headline(cfg, conds, summary: list[dict]) -> str:
    """One sentence per estimator: the first metric clean, and the condition that hurts it most."""
    m = cfg.metrics[0]
    spec = metric(m)
    label, scale, unit, higher = spec.label, spec.scale, spec.unit, spec.higher_is_better
    items = []
    for e in cfg.estimators:
        clean = _value(summary, e.name, "clean", "pose", m)
        others = [(c.name, _value(summary, e.name, c.name, "pose", m)) for c in conds if c.factor != "clean"]
        others = [(n, v) for n, v in others if not math.isnan(v)]
        text = f"<b>{html.escape(e.name)}</b>: {label} {_fmt(clean * scale)} {unit} clean"
        if others:
            worst = min(others, key=lambda nv: nv[1] if higher else -nv[1])
            text += f", worst under {html.escape(worst[0])} ({_fmt(worst[1] * scale)} {unit})"
        if cfg.grasp.episodes > 0:
            g = _value(summary, e.name, "clean", "grasp", "success_rate")
            if not math.isnan(g):
                text += f"; grasp success {g * 100:.0f} % clean"
        items.append(f"<li>{text}</li>")
    return "<ul class=\"headline\">" + "".join(items) + "</ul>"


def _labelled(cfg, out: Path, conds):
    """``cfg`` with every estimator named by its label in the tables (``NAME (GT masks)`` for an estimator
    given ground-truth masks; :func:`simtest.sweeps.cells.labels`)."""
    from dataclasses import replace

    from simtest.sweeps.cells import labels

    names = labels(out, [e.name for e in cfg.estimators], conds)
    return replace(cfg, estimators=tuple(replace(e, name=names[e.name]) for e in cfg.estimators))


def _generation_note(conds) -> str:
    """One paragraph naming the generation conditions and their overrides (empty without any)."""
    gen = [c for c in conds if c.factor in ("sensor", "render")]
    if not gen:
        return ""
    items = ", ".join(f"{html.escape(c.name)} (<code>{html.escape(json.dumps(c.overrides))}</code>)" for c in gen)
    return (f"<p>Generation conditions, the clean scenes generated again with the same ground truth (poses, masks, "
            f"exact depth byte-identical): {items}. They have no grasp cells.</p>")


def write_report(cfg, out: Path, conds) -> dict[str, Path]:
    """Write ``tables.md`` and ``report.html`` from the sweep's ``results.csv`` and ``summary.csv``.

    Args:
        cfg: The sweep config (estimators, metrics, grasp settings, dataset, seed).
        out: Sweep folder holding ``results.csv`` and ``summary.csv`` (:func:`simtest.sweeps.cells.write_tables`).
        conds: The sweep's conditions in table order.
    """
    results = read_csv(out / RESULTS_FILE)
    summary = read_csv(out / SUMMARY_FILE)
    from simtest.sweeps.examples import example_pictures

    examples = example_pictures(cfg, out, conds)  # before the relabelling: cells are found by estimator name
    cfg = _labelled(cfg, out, conds)
    md = markdown_tables(cfg, conds, summary)
    atomic_write_text(out / "tables.md", md)
    plots = _plots(cfg, conds, summary, results)
    est_list = ", ".join(f"{html.escape(e.name)} (<code>{html.escape(e.estimator)}</code>"
                         f"{' ' + html.escape(json.dumps(e.options)) if e.options else ''})" for e in cfg.estimators)
    body = ["<h1>simtest robustness report</h1>", _headline(cfg, conds, summary),
            f"<p>Estimators: {est_list}. Conditions: {html.escape(', '.join(c.name for c in conds))}. "
            f"Seed {cfg.seed}. Occlusion definition: {html.escape(cfg.factors.occlusion_definition)} (2D paste of "
            f"{'object cutouts' if cfg.factors.occlusion_kind == 'objects' else 'noise shapes'} for pose "
            f"evaluation, physical occluders in the grasp scene).</p>", _generation_note(conds),
            _md_to_html_tables(md), '<h2>Plots</h2><div class="plots">']
    for pid, title, data in plots:
        body.append(f'<figure id="{pid}"><img alt="{html.escape(title)}" src="data:image/png;base64,{data}">'
                    f"<figcaption>{html.escape(title)}</figcaption></figure>")
    body.append("</div>")
    if examples:
        body.append('<h2>Example images</h2><div class="grid">')
        for ex in examples:
            body.append(f'<figure class="example" data-condition="{html.escape(ex.condition)}" '
                        f'data-channel="{ex.channel}"><img alt="{html.escape(ex.condition)} {ex.channel}" '
                        f'src="data:image/jpeg;base64,{ex.jpeg_b64}"><figcaption>{html.escape(ex.caption)}'
                        f'</figcaption></figure>')
        body.append("</div>")
    style = ("body{font-family:system-ui,sans-serif;max-width:1100px;margin:2em auto;color:#222}"
             "table{border-collapse:collapse;margin:0.5em 0 1.5em}td,th{border:1px solid #ccc;padding:3px 8px;"
             "text-align:right}th:first-child,td:first-child{text-align:left}thead{background:#f3f3f3}"
             ".grid,.plots{display:flex;flex-wrap:wrap;gap:8px}.headline{font-size:1.05em}.example img{width:240px}figure{margin:0.5em}"
             "figcaption{font-size:0.85em;color:#555}")
    page = ("<!DOCTYPE html><html><head><meta charset=\"utf-8\"><title>simtest robustness report</title>"
            f"<style>{style}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n")
    atomic_write_text(out / "report.html", page)
    return {"tables": out / "tables.md", "report": out / "report.html"}
