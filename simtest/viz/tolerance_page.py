"""The pages of tolerance maps and metric calibration: ``tolerance.png`` / ``calibration.png`` (matplotlib,
Agg) and ``report.html`` with the figures inline, the tables and how the run was made.

Tolerance figure: one row per object, translation errors (mm) on the left and rotation errors (degrees) on
the right, grasp success against the error magnitude per axis with its 95 % Wilson interval as a band, the
success level (90 %) dashed. An axis of continuous symmetry is drawn dotted and its legend entry says that
turning about it is no error.
"""

from __future__ import annotations

import base64
import html
import io
import math
from pathlib import Path
from typing import Any, Sequence

from simtest.io.files import atomic_write_text

__all__ = ["tolerance_figure", "write_tolerance_report", "calibration_figure", "write_calibration_report",
           "AXIS_LABELS"]

#: Legend text of each error axis.
AXIS_LABELS = {"t_x": "t along object x", "t_y": "t along object y", "t_z": "t along object z",
               "t_ray": "t along viewing ray", "r_x": "R about object x", "r_y": "R about object y",
               "r_z": "R about object z"}
_COLOURS = {"t_x": "#d62728", "t_y": "#2ca02c", "t_z": "#1f77b4", "t_ray": "#9467bd", "r_x": "#d62728",
            "r_y": "#2ca02c", "r_z": "#1f77b4"}
_STYLE = ("body{font-family:system-ui,sans-serif;max-width:1100px;margin:2em auto;color:#222}"
          "table{border-collapse:collapse;margin:0.5em 0 1.5em}td,th{border:1px solid #ccc;padding:3px 8px;"
          "text-align:right}th:first-child,td:first-child{text-align:left}thead{background:#f3f3f3}"
          "img{max-width:100%}.note{color:#555;font-size:0.9em}")


def _pyplot():
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def _png_bytes(fig, dpi: int) -> bytes:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight")
    _pyplot().close(fig)
    return buf.getvalue()


def _axis_label(axis: str, symmetry: str) -> str:
    if symmetry == "continuous":
        return f"{AXIS_LABELS[axis]} (continuous symmetry: no error)"
    if symmetry:
        return f"{AXIS_LABELS[axis]} ({symmetry} symmetry)"
    return AXIS_LABELS[axis]


def tolerance_figure(cells: Sequence[dict], level: float = 0.9, dpi: int = 90) -> bytes:
    """PNG bytes of the tolerance figure (see the module doc) from ``tolerance.csv`` rows."""
    plt = _pyplot()
    objects = list(dict.fromkeys(c["object"] for c in cells))
    fig, axes = plt.subplots(len(objects), 2, figsize=(9.6, 2.6 * len(objects) + 0.4), squeeze=False,
                             sharey=True)
    for row, name in enumerate(objects):
        for col, unit in enumerate(("mm", "deg")):
            ax = axes[row][col]
            mine = [c for c in cells if c["object"] == name and c["unit"] == unit]
            for axis in dict.fromkeys(c["axis"] for c in mine):
                pts = sorted((c for c in mine if c["axis"] == axis), key=lambda c: float(c["magnitude"]))
                x = [float(c["magnitude"]) for c in pts]
                y = [float(c["success_rate"]) for c in pts]
                sym = str(pts[0].get("symmetry") or "")
                style = ":" if sym == "continuous" else "-"
                ax.plot(x, y, style, marker="o", ms=3, color=_COLOURS[axis], label=_axis_label(axis, sym))
                ax.fill_between(x, [float(c["ci95_lo"]) for c in pts], [float(c["ci95_hi"]) for c in pts],
                                color=_COLOURS[axis], alpha=0.12, linewidth=0)
            ax.axhline(level, color="#555", ls="--", lw=0.8)
            ax.set_ylim(-0.03, 1.03)
            ax.grid(alpha=0.3)
            ax.set_xlabel("translation error (mm)" if unit == "mm" else "rotation error (deg)", fontsize=8)
            n = max((int(c["episodes"]) for c in mine), default=0)
            ax.set_title(f"{name}: {'translation' if unit == 'mm' else 'rotation'} (n = {n} per point)", fontsize=9)
            ax.tick_params(labelsize=7)
            if mine:
                ax.legend(fontsize=6.5, loc="lower left", frameon=False)
        axes[row][0].set_ylabel("grasp success", fontsize=8)
    fig.suptitle(f"Grasp success vs oracle pose error along one axis (bands: 95 % Wilson; dashed: "
                 f"{100 * level:.0f} %)", fontsize=9)
    fig.tight_layout()
    return _png_bytes(fig, dpi)


def _fmt(v: Any, unit: str) -> str:
    return "–" if v is None else f"{float(v):g} {unit}"


def _tolerance_table(summary: dict) -> str:
    objs = summary["objects"]
    axes = list(next(iter(objs.values()))["axes"]) if objs else []
    head = "".join(f"<th>{html.escape(AXIS_LABELS[a])}</th>" for a in axes)
    rows = []
    for name, o in objs.items():
        z = o["zero_error"]
        cells = []
        for a in axes:
            e = o["axes"][a]
            text = "any (symmetry)" if e["symmetry"] == "continuous" else _fmt(e["tolerated"], e["unit"])
            if e["first_below"] is None and e["symmetry"] != "continuous":
                text += " (grid end)"
            cells.append(f"<td>{html.escape(text)}<br><span class=note>rel. "
                         f"{html.escape(_fmt(e['tolerated_relative'], e['unit']))}</span></td>")
        rows.append(f"<tr><td>{html.escape(name)}<br><span class=note>{html.escape(o['symmetry'])}, zero error "
                    f"{z['successes']}/{z['episodes']}</span></td>{''.join(cells)}</tr>")
    return f"<table><thead><tr><th>object</th>{head}</tr></thead><tbody>{''.join(rows)}</tbody></table>"


def _page(title: str, body: list[str]) -> str:
    return (f"<!DOCTYPE html><html><head><meta charset=\"utf-8\"><title>{html.escape(title)}</title>"
            f"<style>{_STYLE}</style></head><body>\n" + "\n".join(body) + "\n</body></html>\n")


def _run_note(summary: dict, command_line: Sequence[str] | None) -> str:
    run = summary.get("run") or {}
    rate = summary.get("episodes_per_s")
    text = (f"{summary.get('episodes')} episodes in {summary.get('wall_s', 0.0):.1f} s"
            + (f" ({rate:.2f} episodes/s" if rate else " (") + f", {run.get('workers', 1)} worker(s), "
            f"back end {run.get('backend', 'local')}).")
    cmd = f"<pre>{html.escape(' '.join(command_line))}</pre>" if command_line else ""
    return f"<p class=note>{html.escape(text)}</p>{cmd}"


def write_tolerance_report(summary: dict, cells: Sequence[dict], out: str | Path,
                           command_line: Sequence[str] | None = None) -> dict[str, Path]:
    """Write ``tolerance.png`` and ``report.html`` into ``out``; returns their paths."""
    out = Path(out)
    png = tolerance_figure(cells, float(summary.get("level", 0.9)))
    (out / "tolerance.png").write_bytes(png)
    b64 = base64.b64encode(png).decode("ascii")
    level = 100 * float(summary.get("level", 0.9))
    body = ["<h1>Grasp tolerance to pose error</h1>",
            f"<p>Per object and axis, the largest error of the oracle's pose that keeps the grasp success rate "
            f"at or above {level:.0f} % (every smaller magnitude of the grid too); <em>rel.</em>: at or above "
            f"{level:.0f} % of the object's zero-error rate. <em>grid end</em>: success had not fallen by the "
            f"largest magnitude. A rotation about an axis of continuous symmetry moves no surface point: it is "
            f"no error (its curve is drawn dotted, as a check).</p>",
            _run_note(summary, command_line), _tolerance_table(summary),
            f'<figure><img alt="grasp success vs pose error" src="data:image/png;base64,{b64}"></figure>']
    atomic_write_text(out / "report.html", _page("simtest grasp tolerance", body))
    return {"png": out / "tolerance.png", "report": out / "report.html"}


def calibration_figure(rows: Sequence[dict], dpi: int = 90) -> bytes:
    """PNG bytes of the calibration figure: per metric its ROC AUC with the bootstrap interval (bars)."""
    plt = _pyplot()
    rows = [r for r in rows if r.get("auc") is not None and not math.isnan(float(r["auc"]))]
    rows = sorted(rows, key=lambda r: float(r["auc"]))
    fig, ax = plt.subplots(figsize=(6.4, 0.35 * len(rows) + 1.2))
    y = list(range(len(rows)))
    auc = [float(r["auc"]) for r in rows]
    lo = [max(0.0, a - float(r["auc_lo"])) for a, r in zip(auc, rows)]
    hi = [max(0.0, float(r["auc_hi"]) - a) for a, r in zip(auc, rows)]
    ax.barh(y, auc, color="#4c72b0", alpha=0.8)
    ax.errorbar(auc, y, xerr=[lo, hi], fmt="none", ecolor="#222", capsize=2, lw=0.9)
    ax.set_yticks(y, [r["label"] for r in rows], fontsize=7)
    ax.axvline(0.5, color="#888", ls="--", lw=0.8)
    ax.set_xlim(0.4, 1.0)
    ax.set_xlabel("ROC AUC for grasp success (95 % bootstrap interval)", fontsize=8)
    ax.grid(alpha=0.3, axis="x")
    fig.tight_layout()
    return _png_bytes(fig, dpi)


def _bop_text(metric: str, thresholds: Sequence[dict]) -> str:
    """Success among the episodes ``metric`` calls correct, at its smallest, middle and largest BOP threshold."""
    mine = [t for t in thresholds if t["metric"] == metric]
    if not mine:
        return "–"
    picks = [mine[0]] if len(mine) == 1 else [mine[0], mine[len(mine) // 2 - 1], mine[-1]]
    return "; ".join(f"< {float(t['threshold']):g}: {int(t['successes'])}/{int(t['correct'])}" for t in picks)


def _value(v: Any, digits: int = 3) -> str:
    return "–" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{float(v):.{digits}g}"


def _source_text(summary: dict) -> str:
    """Where a calibration's estimates came from: the oracle's random errors, or the real estimators pooled."""
    real = summary.get("estimators")
    if not real:
        return "Oracle estimates with random (not axis-aligned) errors of random size"
    return ("Estimates of real estimators, pooled (" + ", ".join(
        f"{html.escape(n)}: {e['successes']}/{e['episodes']} grasped" for n, e in real.items())
        + "; an episode without an estimate counts as a failure with infinite error)")


def write_calibration_report(summary: dict, rows: Sequence[dict], thresholds: Sequence[dict], out: str | Path,
                             command_line: Sequence[str] | None = None) -> dict[str, Path]:
    """Write ``calibration.png`` and ``calibration.html`` into ``out``; returns their paths."""
    out = Path(out)
    png = calibration_figure(rows)
    (out / "calibration.png").write_bytes(png)
    b64 = base64.b64encode(png).decode("ascii")
    head = ("<tr><th>metric</th><th>AUC</th><th>95 % interval</th><th>best threshold</th><th>Youden J</th>"
            "<th>largest threshold with >= 90 % success</th><th>success where correct at BOP's thresholds</th></tr>")
    body_rows = []
    for r in rows:
        unit = f" {r['unit']}" if r["unit"] else ""
        body_rows.append(
            f"<tr><td>{html.escape(r['label'])}</td><td>{_value(r['auc'])}</td>"
            f"<td>{_value(r['auc_lo'])} – {_value(r['auc_hi'])}</td>"
            f"<td>{_value(r['best_threshold'])}{html.escape(unit)}</td><td>{_value(r['youden'], 2)}</td>"
            f"<td>{_value(r['threshold_90'])}{html.escape(unit)}</td>"
            f"<td>{html.escape(_bop_text(r['metric'], thresholds))}</td></tr>")
    body = ["<h1>Which pose metric predicts grasp success</h1>",
            f"<p>{_source_text(summary)}; per metric the ROC AUC of its error as a predictor of grasp success "
            "(the Mann-Whitney statistic), its 95 % bootstrap interval, the threshold that best separates successes from failures (Youden's J), the largest "
            "threshold whose correct episodes still succeed at least 90 % of the time, and the successes among "
            "the episodes the metric calls correct at BOP's thresholds (smallest, middle, largest).</p>",
            _run_note(summary, command_line),
            f"<table><thead>{head}</thead><tbody>{''.join(body_rows)}</tbody></table>",
            f'<figure><img alt="ROC AUC per metric" src="data:image/png;base64,{b64}"></figure>']
    atomic_write_text(out / "calibration.html", _page("simtest metric calibration", body))
    return {"png": out / "calibration.png", "report": out / "calibration.html"}
