"""Sweep outputs: tidy ``results.csv``, ``summary.csv``, Markdown tables in the classic robustness layout, and
one self-contained ``report.html`` (tables, plots and example images embedded as base64 PNG/JPEG).

Every pose score carries its target count ``n`` and its 95 % interval (:mod:`simtest.sweeps.uncertainty`:
Wilson for proportions of targets, a bootstrap over targets for AR, the AUCs and medians); grasp success its
episode count and Wilson interval. The tables show ``value [low, high]`` with ``n`` in each column's header;
the plots (:mod:`simtest.sweeps.plots`) draw the intervals. The summary at the top names, per estimator, the
condition that hurts the first metric most among those that differ from clean beyond both intervals
(:func:`simtest.sweeps.uncertainty.differs`), and says so when none does.

Table columns, in groups: occlusion (``L0`` = clean, ``L1``..``L3``), corruptions, depth (image-space presets,
then simulated sensors, each by its preset name), renderer (render conditions by name); only the conditions the
sweep config asks for. Generation conditions (depth sensors, renderers) have pose cells only, so the grasp
table leaves them out.
"""

from __future__ import annotations

import html
import json
import math
import re
from pathlib import Path

from simtest.io.files import atomic_write_text, read_csv
from simtest.metrics.registry import Metric, metric
from simtest.sweeps.cells import RESULTS_FILE, SUMMARY_FILE, Scores
from simtest.sweeps.plots import (Plot, column_label, error_vs_grasp_plot, fit_logistic, grasp_occlusion_plot,
                                  metric_plot)
from simtest.sweeps.uncertainty import Interval, differs

__all__ = ["write_report", "fit_logistic", "markdown_tables", "score_text", "INTERVAL_NOTE"]

#: What the intervals of the tables are, said under them.
INTERVAL_NOTE = ("Each score: value [95 % interval]; n: targets (pose) or episodes (grasp) per cell. Intervals: "
                 "Wilson for proportions of targets or episodes, percentile bootstrap over targets for AR, AUC "
                 "and medians; none for AP.")

#: Grasp success as a score of the tables (a fraction of episodes, shown in percent).
_GRASP = Metric("success_rate", "grasp success", "fraction of episodes that lifted and held the object", digits=0)


def _groups(conds) -> list[tuple[str, list]]:
    groups = [("", [c for c in conds if c.factor in ("clean", "occlusion")]),
              ("corruption", [c for c in conds if c.factor == "corruption"]),
              ("depth", [c for c in conds if c.factor in ("depth", "sensor")]),
              ("renderer", [c for c in conds if c.factor == "render"])]
    return [(g, cs) for g, cs in groups if cs]


def score_text(key: str, value: float, iv: Interval, digits: int | None = None) -> str:
    """``value [low, high]`` of a score in display units (``-`` when missing; no brackets without an
    interval)."""
    spec = _GRASP if key == _GRASP.key else metric(key)
    if math.isnan(value):
        return "-"
    text = spec.format(value, digits)
    return f"{text} [{spec.format(iv.low, digits)}, {spec.format(iv.high, digits)}]" if iv.known else text


def _column_headers(cols, scores: Scores, names: list[str], kind: str, key: str) -> tuple[list[str], bool]:
    """Column headers with ``(n=N)`` when every estimator's score of the column has the same count; False
    when some column has differing counts (its cells then carry their own)."""
    heads, shared = [], True
    for c in cols:
        ns = {scores.get(e, c.name, kind, key)[1].n for e in names} - {0}
        heads.append(column_label(c) + (f" (n={ns.pop()})" if len(ns) == 1 else ""))
        shared = shared and len(ns) <= 1
    return heads, shared


def _table(cols, scores: Scores, names: list[str], kind: str, key: str, digits: int | None = None) -> str:
    heads, shared = _column_headers(cols, scores, names, kind, key)
    lines = ["| estimator | " + " | ".join(heads) + " |", "|---|" + "|".join("---:" for _ in cols) + "|"]
    for e in names:
        cells = []
        for c in cols:
            v, iv = scores.get(e, c.name, kind, key)
            cells.append(score_text(key, v, iv, digits) + ("" if shared or not iv.n else f" n={iv.n}"))
        lines.append(f"| {e} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def markdown_tables(cfg, conds, summary: list[dict]) -> str:
    """One table per metric: rows estimators, columns L0 L1 L2 L3 | corruptions | depth | renderers, each
    cell ``value [95 % interval]`` and each header ``(n=targets)``; then grasp success over episodes."""
    scores = Scores(summary)
    names = [e.name for e in cfg.estimators]
    cols = [c for _, cs in _groups(conds) for c in cs]
    parts = []
    for m in cfg.metrics:
        spec = metric(m)
        parts.append(f"### {spec.label} ({spec.unit})\n\n" + _table(cols, scores, names, "pose", m))
    if cfg.grasp.episodes > 0:
        grasp_cols = [c for c in cols if c.factor not in ("sensor", "render")]
        parts.append("### Grasp success (%; occlusion is physical in the grasp scene)\n\n" +
                     _table(grasp_cols, scores, names, "grasp", "success_rate", digits=0))
    groups = ", ".join(f"{g or 'occlusion'}: {' '.join(column_label(c) for c in cs)}" for g, cs in _groups(conds))
    return ("## Robustness tables\n\nColumns (" + groups + "). " + INTERVAL_NOTE + "\n\n" +
            "\n\n".join(parts) + "\n")


def _plots(cfg, conds, summary: list[dict], results: list[dict]) -> list[Plot]:
    """Every plot of the report, in order."""
    scores = Scores(summary)
    plots = [metric_plot(cfg, conds, scores, m) for m in cfg.metrics]
    if cfg.grasp.episodes > 0:
        plots += [grasp_occlusion_plot(cfg, conds, scores), error_vs_grasp_plot(results)]
    return plots


_INTERVAL = re.compile(r" (\[[^\]]*\])( n=\d+)?$")


def _cell_html(text: str) -> str:
    """A table cell: the interval (and a per-cell count) in a smaller grey span."""
    m = _INTERVAL.search(text)
    if not m:
        return html.escape(text)
    return html.escape(text[:m.start()]) + f' <span class="ci">{html.escape(m.group(0).strip())}</span>'


def _md_to_html_tables(md: str) -> str:
    """The Markdown tables of :func:`markdown_tables` as HTML."""
    out, rows = [], []

    def flush() -> None:
        if rows:
            head, body = rows[0], rows[2:]
            out.append("<table><thead><tr>" + "".join(f"<th>{html.escape(c)}</th>" for c in head) +
                       "</tr></thead><tbody>" + "".join("<tr>" + "".join(f"<td>{_cell_html(c)}</td>" for c in r)
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
    """One sentence per estimator: the first metric clean, with its interval and count, and the condition
    that hurts it most among those that differ from clean beyond the 95 % intervals (none: said so)."""
    scores = Scores(summary)
    m = cfg.metrics[0]
    spec = metric(m)
    items = []
    for e in cfg.estimators:
        clean = scores.get(e.name, "clean", "pose", m)
        text = (f"<b>{html.escape(e.name)}</b>: {spec.label} {score_text(m, *clean)} {spec.unit} clean"
                + (f" (n={clean[1].n})" if clean[1].n else ""))
        others = [(c.name, scores.get(e.name, c.name, "pose", m)) for c in conds if c.factor != "clean"]
        worse = [(n, s) for n, s in others if differs(s, clean) and
                 (s[0] < clean[0] if spec.higher_is_better is not False else s[0] > clean[0])]
        if worse:
            name, (v, iv) = min(worse, key=lambda ns: ns[1][0] if spec.higher_is_better is not False else -ns[1][0])
            text += f", worst under {html.escape(name)} ({score_text(m, v, iv)} {spec.unit}, n={iv.n})"
        elif any(not math.isnan(s[0]) for _, s in others):
            text += ", no condition worse than clean beyond the 95 % intervals"
        if cfg.grasp.episodes > 0:
            g = scores.get(e.name, "clean", "grasp", "success_rate")
            if not math.isnan(g[0]):
                text += f"; grasp success {score_text('success_rate', *g, digits=0)} % clean (n={g[1].n})"
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
    for plot in plots:
        caption = plot.title + (f": {plot.note}" if plot.note else "")
        body.append(f'<figure id="{plot.id}"><img alt="{html.escape(plot.title)}" '
                    f'src="data:image/png;base64,{plot.png_b64}"><figcaption>{html.escape(caption)}'
                    f"</figcaption></figure>")
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
             "figcaption{font-size:0.85em;color:#555;max-width:560px}.ci{font-size:0.8em;color:#666}")
    page = ("<!DOCTYPE html><html><head><meta charset=\"utf-8\"><title>simtest robustness report</title>"
            f"<style>{style}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n")
    atomic_write_text(out / "report.html", page)
    return {"tables": out / "tables.md", "report": out / "report.html"}
