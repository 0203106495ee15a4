"""Tables of an evaluation report: a Markdown table per object and overall, and a terminal summary.

Columns, labels, units and number formats come from :mod:`simtest.metrics.registry`; this module only lays
them out.
"""

from __future__ import annotations

from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from simtest.metrics.bop19 import VISIB_GT_MIN
from simtest.metrics.registry import NDEG_MCM, metric

__all__ = ["format_table", "category_table", "metric_table", "overall_table", "failure_counts", "TABLE_METRICS",
           "SUMMARY_METRICS", "CATEGORY_METRICS", "DETECTION_TABLE_METRICS", "DETECTION_CATEGORY_METRICS",
           "DETECTION_SUMMARY_METRICS"]

#: Metric keys of the Markdown table's columns (after the object name), in order. ``ar_vsd`` is dropped when
#: VSD was not evaluated.
TABLE_METRICS: tuple[str, ...] = ("num_targets", "add_s_or_add_01d", "auc_adds", "auc_add_s_or_add", "adds_lt_2cm",
                                  "acc_pi_6", "acc_pi_18", "median_re_deg", "median_te_m", "5deg5cm", "10deg5cm",
                                  "ar", "ar_vsd", "ar_mssd", "ar_mspd")
#: Metric keys of the per-category table's columns (after the category name), in order.
CATEGORY_METRICS: tuple[str, ...] = ("num_objects", *TABLE_METRICS)
#: The same for the detection task (``settings.task == "detection"``): BOP24 AP and classification first.
DETECTION_TABLE_METRICS: tuple[str, ...] = ("num_targets", "ap", "ap_mssd", "ap_mspd", "ap_mssd_mm", "cls_acc",
                                            "cls_acc_pi_6", "cls_acc_pi_18", "cls_median_re_deg",
                                            "add_s_or_add_01d", "median_te_m")
DETECTION_CATEGORY_METRICS: tuple[str, ...] = ("num_objects", "num_targets", "cls_acc", "cls_acc_pi_6",
                                               "cls_acc_pi_18", "cls_median_re_deg", "ap", "ap_mssd", "ap_mspd",
                                               "ap_mssd_mm")
DETECTION_SUMMARY_METRICS: tuple[str, ...] = (
    "ap", "ap_mssd", "ap_mspd", "ap_mssd_mm", "cls_acc", "cls_acc_pi_6", "cls_acc_pi_18", "cls_median_re_deg",
    "num_targets", "num_estimates", "num_failures", "mean_time_per_image_s")
#: Metric keys of the terminal summary, in order.
SUMMARY_METRICS: tuple[str, ...] = (
    "add_s_or_add_01d", "auc_adds", "auc_add_s_or_add", "adds_lt_2cm", "acc_pi_6", "acc_pi_18", "median_re_deg",
    "median_te_m", *(f"{n:g}deg{m:g}cm" for n, m in NDEG_MCM), "ar", "ar_vsd", "ar_mssd", "ar_mspd",
    "num_targets", "num_estimates", "num_failures", "mean_time_per_image_s")


def metric_table(first: str, metrics: Sequence[str], rows: list[tuple[str, dict[str, Any]]],
                 vsd_on: bool = True) -> str:
    """A Markdown table: column ``first`` then one per metric key (header, format and unit from the registry;
    without VSD, ``ar_vsd`` is left out and AR is named for its two terms); one line per ``(name, values)`` row;
    ends with a newline."""
    keys = [k for k in metrics if vsd_on or k != "ar_vsd"]
    cols = [first, *[("AR (MSSD, MSPD) [%]" if k == "ar" and not vsd_on else metric(k).header) for k in keys]]
    head = "| " + " | ".join(cols) + " |\n|" + "|".join(["---"] + ["---:"] * (len(cols) - 1)) + "|\n"
    return head + "".join("| " + " | ".join([name] + [metric(k).format(values.get(k)) for k in keys]) + " |\n"
                          for name, values in rows)


def _vsd_on(report: Any) -> bool:
    return bool(report.settings.get("vsd", True))


def _detection(report: Any) -> bool:
    return report.settings.get("task") == "detection"


def format_table(report: Any) -> str:
    """Markdown tables of an :class:`~simtest.evaluation.run.EvalReport`: one row per object and one overall; units in
    the headers (percent, degrees, centimetres)."""
    rows = [(f"{report.object_names.get(o, o)} ({o})", m) for o, m in sorted(report.per_object.items())]
    keys = DETECTION_TABLE_METRICS if _detection(report) else TABLE_METRICS
    keys = (*keys, "grasp_tolerance") if "grasp_tolerance" in report.overall else keys
    keys = _chosen(report, keys, ("num_targets",))
    table = metric_table("Object", keys, rows + [("**All**", report.overall)], _vsd_on(report))
    s = report.settings
    o = report.overall
    title = s.get("estimator") or s.get("results", "")
    footer = (f"\n{report.num_images} images, {o['num_targets']} targets (visib_fract >= {VISIB_GT_MIN}), "
              f"{o.get('num_estimates', 0)} estimates, {o.get('num_failures', 0)} failures"
              f"{_kinds_text(report.failures)}; "
              f"time per image: mean {metric('mean_time_per_image_s').format(o.get('mean_time_per_image_s'), 3)} s.\n"
              + _interval_line(o) +
              "ADD(-S): ADD-S for symmetric objects. AUC: YCB-Video VOC-style, 0-10 cm. Rotation errors are the "
              "smallest over the object's symmetries; misses count as 180°. AR: BOP19 Average Recall.\n"
              + (_DETECTION_NOTE if _detection(report) else ""))
    notes = s.get("data_notes") or []
    footer += "".join(f"Data: {line}.\n" for line in notes)
    text = f"### {title} on {Path(s.get('dataset', '')).name} / {s.get('split', '')}\n\n" + table + footer
    per_category = getattr(report, "per_category", None)
    return text + ("\n" + category_table(report) if per_category else "")


def _chosen(report: Any, keys: tuple[str, ...], always: tuple[str, ...]) -> tuple[str, ...]:
    """``keys`` restricted to the metrics the run's settings name (``show_metrics``: ``simtest eval --metrics``),
    in their order, with the counts ``always`` kept; all of ``keys`` when none are named."""
    chosen = report.settings.get("show_metrics")
    if not chosen:
        return keys
    return tuple(k for k in keys if k in always) + tuple(k for k in chosen if k not in always)


def _interval_line(overall: dict[str, Any]) -> str:
    """``95 % intervals (Wilson, over targets): ADD(-S)-0.1d 41.6-48.8 %, ...`` of the overall proportions."""
    ci = overall.get("ci95") or {}
    parts = [f"{metric(k).label} {metric(k).format(ci[k][0])}-{metric(k).format(ci[k][1])} {metric(k).unit}"
             for k in ("add_s_or_add_01d", "adds_lt_2cm", "acc_pi_6", "5deg5cm") if k in ci]
    line = f"95 % intervals (Wilson, over targets): {', '.join(parts)}.\n" if parts else ""
    cs = overall.get("ci95_scenes") or {}
    scene_parts = [f"{metric(k).label} {metric(k).format(cs[k][0])}-{metric(k).format(cs[k][1])} {metric(k).unit}"
                   for k in ("add_s_or_add_01d", "adds_lt_2cm", "acc_pi_6", "5deg5cm") if k in cs]
    if scene_parts:
        line += (f"95 % intervals (bootstrap over {overall.get('num_scenes')} scenes, as scenes differ more than "
                 f"targets): {', '.join(scene_parts)}.\n")
    return line


_DETECTION_NOTE = ("Detection task: no target ids or counts given; at most 100 estimates per image. AP: BOP24 "
                   "(mean of AP_MSSD and AP_MSPD; COCO-style, 101 recall points, instances with visib_fract < 0.1 "
                   "ignored), per object, All = mean over objects. Cls: top-1 category of the class-agnostic "
                   "match (nearest centre within half the diameter); Cls Acc@π/6, Acc@π/18 also need the "
                   "rotation; ADD(-S) and te by the per-object nearest-translation matching.\n")


def category_table(report: Any) -> str:
    """A Markdown table with one row per object category (``report.per_category``) and one overall, headed
    ``#### Per category``; empty when the report has no categories."""
    if not getattr(report, "per_category", None):
        return ""
    overall = {**report.overall, "num_objects": sum(m["num_objects"] for m in report.per_category.values())}
    table = metric_table("Category", DETECTION_CATEGORY_METRICS if _detection(report) else CATEGORY_METRICS,
                         [*report.per_category.items(), ("**All**", overall)], _vsd_on(report))
    return (f"#### Per category ({len(report.per_category)} categories)\n\n" + table +
            "Acc@π/6, Acc@π/18: the viewpoint protocol's rotation accuracy, e = ||logm(R_p^T R_gt)||_F / √2 "
            "(smallest over the object's symmetries; misses count as π).\n")


def overall_table(report: Any) -> str:
    """A short plain-text summary of the overall scores (for terminals): label, value and unit per line."""
    o = report.overall
    items = []
    keys = DETECTION_SUMMARY_METRICS if _detection(report) else SUMMARY_METRICS
    keys = (*keys, "grasp_tolerance") if "grasp_tolerance" in o else keys
    for k in _chosen(report, keys, ("num_targets", "num_estimates", "num_failures", "mean_time_per_image_s")):
        m = metric(k)
        digits = 2 if k in ("median_re_deg", "median_te_m") else None
        text = m.format(o.get(k), digits) if k in o else ""
        if k == "num_failures":
            text += _kinds_text(report.failures)
        ci = (o.get("ci95") or {}).get(k)
        if ci is not None and k in o:
            text += f" [{m.format(ci[0])}, {m.format(ci[1])}]"
        items.append((m.label, f"{text} {m.unit}".rstrip()))
    w = max(len(k) for k, _ in items)
    return "\n".join(f"{k:<{w}}  {v}" for k, v in items)


def failure_counts(failures: Iterable[dict[str, Any]]) -> dict[str, int]:
    """``{kind: number of failures}``, kinds in order of first appearance."""
    out: dict[str, int] = {}
    for f in failures:
        out[f["kind"]] = out.get(f["kind"], 0) + 1
    return out


def _kinds_text(failures: list[dict[str, Any]]) -> str:
    """``" (timeout 2, exception 1)"``: how many failures of each kind; ``""`` without failures."""
    counts = failure_counts(failures)
    return " (" + ", ".join(f"{k} {n}" for k, n in counts.items()) + ")" if counts else ""
