"""A grasp run's summary and files: success rate with a 95 % Wilson interval (:mod:`simtest.metrics.intervals`),
per object and per failure reason, pose-error medians; ``episodes.csv``, ``summary.json`` and ``summary.md``.

Units: pose errors in metres and degrees (the Markdown shows millimetres), times in seconds.
"""

from __future__ import annotations

import csv
import math
from pathlib import Path

import numpy as np

from simtest.envs.episode import FAILURE_REASONS
from simtest.io.files import atomic_write_json, jsonable
from simtest.metrics.intervals import wilson_interval

__all__ = ["CSV_COLUMNS", "summarize", "summary_markdown", "write_run_outputs", "percent", "rotation_error",
           "raw_rotation_error", "failure_words"]

#: Columns of ``episodes.csv`` (units: m, deg, s). The rotation error is ``re_sym_deg`` (the smallest over the
#: object's symmetries, as ``simtest eval`` scores it); the raw geodesic one is kept as ``re_raw_deg`` (files of
#: earlier releases call it ``re_deg``: :func:`raw_rotation_error` reads either). ``error`` says why an episode
#: failed in words (the estimator's message, or the planner's rejections by cause).
CSV_COLUMNS = ["episode", "seed", "target_obj_id", "target_name", "success", "reason", "add_s", "re_sym_deg",
               "re_raw_deg", "te", "mssd", "estimate_s", "wall_s", "sim_s", "lift_height", "occlusion",
               "occluded_fraction", "visible_pixels", "grasp_index", "approach_tilt_deg", "error", "traceback",
               "warnings", "planner_obstacles"]


def _nanmedian(values: list[float]) -> float | None:
    """The median of the finite values, None without one."""
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], dtype=np.float64)
    return float(np.median(v)) if len(v) else None


def rotation_error(row: dict):
    """The symmetry-aware rotation error (degrees) of an episode row or CSV record (``re_sym_deg``; rows of
    earlier releases without it: their ``re_deg``)."""
    value = row.get("re_sym_deg")
    return row.get("re_deg") if value is None or value == "" else value


def raw_rotation_error(row: dict):
    """The raw geodesic rotation error (degrees) of an episode row or CSV record (``re_raw_deg``, or the
    ``re_deg`` of rows and files of earlier releases)."""
    value = row.get("re_raw_deg")
    return row.get("re_deg") if value is None or value == "" else value


def _cm(row: dict, key: str) -> str:
    """``row[key]`` (metres) in centimetres with one decimal, ``"?"`` when missing or not finite."""
    try:
        v = float(row.get(key))
    except (TypeError, ValueError):
        return "?"
    return f"{100 * v:.1f}" if math.isfinite(v) else "?"


def failure_words(row: dict) -> str:
    """Why an episode failed, in words: its ``error`` when the episode said why (the estimator's message, the
    planner's rejections by cause), else a sentence from its reason and measurements; ``""`` for a success."""
    reason = str(row.get("reason", ""))
    error = str(row.get("error") or "")
    if reason in ("", "none") or error:
        return error
    obj = f"{row.get('target_name')} (obj_id {row.get('target_obj_id')})"
    lift = _cm(row, "lift_height")
    words = {
        "no_estimate": f"no_estimate: the estimator returned no pose for {obj} "
                       f"({row.get('visible_pixels')} visible pixels)",
        "missed": f"missed: after closing, {obj} does not touch both fingers (lifted {lift} cm)",
        "slipped": f"slipped: {obj} was grasped but not held at least 10 cm up for the whole hold "
                   f"(lifted {lift} cm)",
        "collision": "collision: the arm pushed against the table or another object on its way to the grasp",
        "ik_failure": "ik_failure: no inverse-kinematics solution reaches the planned motion",
    }
    return words.get(reason, reason)


def summarize(rows: list[dict]) -> dict:
    """Success rate with a 95 % Wilson interval, per object and per failure reason, and pose-error medians.

    Returns:
        ``{"episodes", "successes", "success_rate", "ci95": [lo, hi], "by_object": {name: {"obj_id", "n",
        "successes", "success_rate", "ci95"}}, "by_reason": {reason: count}, "median_add_s", "median_re_deg",
        "median_te", "median_mssd", "median_wall_s", "median_estimate_s"}`` (errors in m / deg, times in s;
        the rotation error is ``re_sym``, the smallest over the object's symmetries, as in ``simtest eval``).
    """
    n = len(rows)
    k = sum(bool(r["success"]) for r in rows)
    lo, hi = wilson_interval(k, n)
    by_obj: dict[str, dict] = {}
    for r in rows:
        e = by_obj.setdefault(r["target_name"], {"obj_id": int(r["target_obj_id"]), "n": 0, "successes": 0})
        e["n"] += 1
        e["successes"] += int(bool(r["success"]))
    for e in by_obj.values():
        e["success_rate"] = e["successes"] / e["n"]
        e["ci95"] = list(wilson_interval(e["successes"], e["n"]))
    by_obj = dict(sorted(by_obj.items(), key=lambda kv: kv[1]["obj_id"]))
    reasons = {reason: sum(r["reason"] == reason for r in rows) for reason in FAILURE_REASONS}
    return {
        "episodes": n, "successes": k, "success_rate": k / n if n else 0.0, "ci95": [lo, hi],
        "by_object": by_obj, "by_reason": reasons,
        "median_add_s": _nanmedian([r["add_s"] for r in rows]),
        "median_re_deg": _nanmedian([rotation_error(r) for r in rows]),
        "median_te": _nanmedian([r["te"] for r in rows]),
        "median_mssd": _nanmedian([r["mssd"] for r in rows]),
        "median_wall_s": _nanmedian([r["wall_s"] for r in rows]),
        "median_estimate_s": _nanmedian([r["estimate_s"] for r in rows]),
    }


def percent(x: float) -> str:
    """``x`` (a fraction) as a percentage with one decimal, e.g. ``0.5 -> "50.0%"``."""
    return f"{100 * x:.1f}%"


def summary_markdown(s: dict) -> str:
    """The summary as Markdown tables."""
    lo, hi = s["ci95"]
    cfg = s.get("config") or {}
    lines = ["# Closed-loop grasping", ""]
    if cfg:
        opts = ", ".join(f"{k}={v}" for k, v in (cfg.get("estimator_options") or {}).items())
        lines += [f"Estimator `{s.get('estimator_label') or cfg.get('estimator')}`" + (f" ({opts})" if opts else "") +
                  f", objects `{cfg.get('objects')}`, occlusion {cfg.get('occlusion')}, "
                  f"weather {cfg.get('weather') or 'none'}"
                  + (f" (severity {cfg.get('severity')})" if cfg.get("weather") else "")
                  + f", depth noise {cfg.get('depth_noise') or 'none'}"
                  f", depth sensor {cfg.get('depth_sensor', 'none')}"
                  f", distractors {cfg.get('n_distractors')}, "
                  f"seed {cfg.get('seed')}, planner obstacles {cfg.get('planner_obstacles', 'sim')}"
                  + ("" if "looks" not in cfg else f", looks {'generator' if cfg['looks'] else 'plain'}") + ".", ""]
    if s.get("command_line"):
        lines += ["```", " ".join(s["command_line"]), "```", ""]
    lines += [f"**Success: {s['successes']}/{s['episodes']} = {percent(s['success_rate'])}** "
              f"(95% Wilson CI {percent(lo)} - {percent(hi)})", ""]

    def fmt(v: float | None, scale: float = 1.0, digits: int = 1) -> str:
        return "-" if v is None else f"{v * scale:.{digits}f}"

    lines += ["| median ADD(-S) mm | median re_sym deg | median te mm | median MSSD mm | median episode s |",
              "|---:|---:|---:|---:|---:|",
              f"| {fmt(s['median_add_s'], 1000)} | {fmt(s['median_re_deg'])} | {fmt(s['median_te'], 1000)} | "
              f"{fmt(s['median_mssd'], 1000)} | {fmt(s['median_wall_s'], 1, 2)} |", ""]
    lines += ["## Per object", "", "| obj_id | object | episodes | success | 95% CI |", "|---:|---|---:|---:|---|"]
    for name, e in s["by_object"].items():
        lines.append(f"| {e['obj_id']} | {name} | {e['n']} | {percent(e['success_rate'])} | "
                     f"{percent(e['ci95'][0])} - {percent(e['ci95'][1])} |")
    lines += ["", "## Outcomes", "", "| reason | episodes |", "|---|---:|"]
    for reason, count in s["by_reason"].items():
        lines.append(f"| {reason} | {count} |")
    return "\n".join(lines) + "\n"


def write_run_outputs(rows: list[dict], summary: dict, out: Path) -> None:
    """Write a run's ``episodes.csv`` (``rows``, :data:`CSV_COLUMNS`; non-finite numbers as empty cells),
    ``summary.json`` (both atomically) and ``summary.md`` (``summary``) into the folder ``out``."""
    tmp = out / ".episodes.csv.partial"
    with tmp.open("w", newline="", encoding="utf-8") as f:
        w = csv.DictWriter(f, fieldnames=CSV_COLUMNS, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            r = {**r, "re_raw_deg": raw_rotation_error(r)}
            w.writerow({k: ("" if isinstance(v, float) and not math.isfinite(v) else v) for k, v in r.items()})
    tmp.replace(out / "episodes.csv")
    atomic_write_json(out / "summary.json", jsonable(summary))
    (out / "summary.md").write_text(summary_markdown(summary), encoding="utf-8")
