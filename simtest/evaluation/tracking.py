"""Scoring an evaluation as tracking: per-frame errors along each object's track, tables, CSV and a plot.

A scene of a sequence dataset (``simtest generate --rig sequence``) is one sequence; its images are frames in
order, and an object instance (BOP ``gt_id``) is one track. Per frame, the instances with ``visib_fract >=
0.1`` are the targets (as in :mod:`simtest.evaluation.run`) and estimates are matched to them as there (per object id,
by decreasing score, nearest translation). The per-frame errors and their summaries are defined in
:mod:`simtest.metrics.tracking` (3D IoU of the model's bounding box, R_err in degrees, T_err in centimetres,
IoU25/50/75, n deg m cm, loss at the first frame failing 10 deg 5 cm or without an estimate).

Outputs (:func:`write_tracking`): ``tracking.csv`` (one row per target-frame), ``tracking.md`` (a table per
object and overall), ``tracking.json`` and ``tracking.png`` (rotation and translation error over the frames).
"""

from __future__ import annotations

import json
from collections import defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from simtest.io import bop
from simtest.io.dataset import ImageRef
from simtest.io.files import atomic_write_bytes, atomic_write_text, csv_text, jsonable
from simtest.metrics.bop19 import ResultRow
from simtest.metrics.pose import re_sym
from simtest.metrics.registry import metric
from simtest.metrics.tracking import LOSS_CM, LOSS_DEG, box_iou, first_loss, summarize_frames
from simtest.evaluation.scoring import image_matches
from simtest.evaluation.tables import metric_table

__all__ = ["TrackingReport", "is_sequence_dataset", "score_tracking", "tracking_table", "write_tracking",
           "TRACKING_METRICS", "FRAME_COLUMNS"]

#: Metric keys of the tracking table's columns, in order (labels and units from the registry).
TRACKING_METRICS: tuple[str, ...] = ("num_tracks", "num_targets", "iou25", "iou50", "iou75", "5deg2cm", "5deg5cm",
                                     "10deg5cm", "mean_re_deg", "mean_te_m", "tracked_fraction")
#: Columns of ``tracking.csv``.
FRAME_COLUMNS = ["scene_id", "im_id", "frame", "gt_id", "obj_id", "category", "visib_fract", "matched", "re_deg",
                 "te_cm", "iou", "lost"]
#: Symmetry discretisation for the IoU (radians): 20 steps per turn, as the NOCS protocol.
_IOU_SYM_STEP = 2.0 * np.pi / 20


@dataclass
class TrackingReport:
    """Tracking scores of one evaluation.

    Attributes:
        frames: One dict per target-frame (:data:`FRAME_COLUMNS`; degrees, centimetres).
        overall: Aggregates over every target-frame and track (:data:`TRACKING_METRICS` keys).
        per_object: ``{obj_id: aggregates}``.
        object_names: ``{obj_id: name}``.
        settings: Label of the estimator, dataset, loss thresholds.
    """

    frames: list[dict[str, Any]]
    overall: dict[str, Any]
    per_object: dict[int, dict[str, Any]]
    object_names: dict[int, str]
    settings: dict[str, Any] = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {"settings": self.settings, "overall": jsonable(self.overall),
                "per_object": {str(k): {"name": self.object_names.get(k, str(k)), **jsonable(v)}
                               for k, v in sorted(self.per_object.items())},
                "definitions": {k: metric(k).definition for k in TRACKING_METRICS}}


def is_sequence_dataset(root: str | Path) -> bool:
    """Whether the dataset's ``manifest.json`` says it was generated with ``rig = "sequence"`` (False without a
    manifest)."""
    path = Path(root) / "manifest.json"
    if not path.is_file():
        return False
    return bop.read_json(path).get("config", {}).get("rig") == "sequence"


def _frame_rows(refs: Sequence[ImageRef], results: Iterable[ResultRow], objects) -> list[dict[str, Any]]:
    """Per target-frame errors (``lost`` still unset), frames numbered from 0 within each scene."""
    models = {o.obj_id: o for o in objects}
    syms: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # (fine for R_err, 20 steps per turn for the IoU)
    rows: list[dict[str, Any]] = []
    scene, frame = None, 0
    for ref, targets, ests, match in image_matches(refs, results, models):
        frame = frame + 1 if ref.scene_id == scene else 0
        scene = ref.scene_id
        for j, (gt_id, g) in enumerate(targets):
            obj = models[g.obj_id]
            if g.obj_id not in syms:
                syms[g.obj_id] = (obj.symmetry_transforms(), obj.symmetry_transforms(max_step=_IOU_SYM_STEP))
            row = {"scene_id": ref.scene_id, "im_id": ref.im_id, "frame": frame, "gt_id": gt_id, "obj_id": g.obj_id,
                   "category": obj.category, "visib_fract": float(g.visib_fract), "matched": j in match,
                   "re_deg": float("nan"), "te_cm": float("nan"), "iou": 0.0}
            if j in match:
                e, R_g, t_g = ests[match[j]], g.T_cam_obj.R, g.T_cam_obj.t
                row.update(re_deg=re_sym(e.R, R_g, syms[g.obj_id][0]), te_cm=100.0 * float(np.linalg.norm(e.t - t_g)),
                           iou=box_iou(e.R, e.t, R_g, t_g, obj.bbox, syms[g.obj_id][1]))
            rows.append(row)
    return rows


def _track_fractions(rows: list[dict[str, Any]]) -> dict[tuple[int, int], tuple[int, float]]:
    """``{(scene_id, gt_id): (obj_id, tracked fraction)}``; marks each row ``lost`` from its track's first loss."""
    tracks: dict[tuple[int, int], list[dict[str, Any]]] = defaultdict(list)
    for r in rows:
        tracks[(r["scene_id"], r["gt_id"])].append(r)
    out = {}
    for key, tr in tracks.items():
        k = first_loss([r["re_deg"] for r in tr], [r["te_cm"] for r in tr], [r["matched"] for r in tr])
        for i, r in enumerate(tr):
            r["lost"] = i >= k
        out[key] = (tr[0]["obj_id"], k / len(tr))
    return out


def score_tracking(root: str | Path, results: Iterable[ResultRow], refs: Sequence[ImageRef], objects,
                   label: str = "") -> TrackingReport:
    """Tracking scores of the estimates ``results`` (metres) on the images ``refs`` (scenes in order, frames in
    order within each scene); see the module doc.

    Args:
        root: Dataset root (recorded in the settings).
        results: Estimates as BOP result rows (metres).
        refs: The evaluated images (:func:`simtest.io.dataset.select_images`).
        objects: The dataset's object set.
        label: The estimator's label (e.g. ``track-icp (GT init)``).
    """
    rows = _frame_rows(refs, results, objects)
    fractions = _track_fractions(rows)
    names = {o.obj_id: o.name for o in objects}

    def summary(sel_rows: list[dict[str, Any]], fr: list[float]) -> dict[str, Any]:
        out: dict[str, Any] = summarize_frames(sel_rows) if sel_rows else {}
        out["num_tracks"] = len(fr)
        out["tracked_fraction"] = float(np.mean(fr)) if fr else float("nan")
        return out

    per_object = {}
    for o in sorted({r["obj_id"] for r in rows}):
        per_object[o] = summary([r for r in rows if r["obj_id"] == o], [f for oo, f in fractions.values() if oo == o])
    overall = summary(rows, [f for _, f in fractions.values()])
    settings = {"estimator": label, "dataset": str(root), "loss_deg": LOSS_DEG, "loss_cm": LOSS_CM,
                "num_sequences": len({r.scene_id for r in refs}), "num_frames": len(refs)}
    return TrackingReport(rows, overall, per_object, names, settings)


def tracking_table(report: TrackingReport) -> str:
    """A Markdown table: one row per object, one overall; labels and units from the registry."""
    rows = [(f"{report.object_names.get(o, o)} ({o})", v) for o, v in sorted(report.per_object.items())]
    s = report.settings
    return (f"### Tracking: {s.get('estimator', '')} on {Path(s.get('dataset', '')).name} "
            f"({s.get('num_sequences', 0)} sequences, {s.get('num_frames', 0)} frames)\n\n"
            + metric_table("Object", TRACKING_METRICS, rows + [("**All**", report.overall)])
            + "\nIoU: exact 3D IoU of the model's bounding box at the estimated vs the ground-truth pose (best over "
            "symmetries; misses 0). R_err, T_err: means over frames with an "
            f"estimate. tracked: mean fraction of a track's frames before its first loss (no estimate, R_err > "
            f"{s.get('loss_deg', LOSS_DEG):g}° or T_err > {s.get('loss_cm', LOSS_CM):g} cm).\n")


def _plot(report: TrackingReport) -> bytes:
    """PNG of R_err (degrees) and T_err (centimetres) over the frame index: one thin line per track, the mean
    over tracks per frame in black (misses left out)."""
    import io

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(9, 3.4))
    tracks: dict[tuple[int, int], list[dict[str, Any]]] = defaultdict(list)
    for r in report.frames:
        tracks[(r["scene_id"], r["gt_id"])].append(r)
    for ax, key, unit in ((axes[0], "re_deg", "deg"), (axes[1], "te_cm", "cm")):
        per_frame: dict[int, list[float]] = defaultdict(list)
        for tr in tracks.values():
            x = [r["frame"] for r in tr]
            y = [r[key] if r["matched"] else np.nan for r in tr]
            ax.plot(x, y, lw=0.6, alpha=0.35, color="tab:blue")
            for xi, yi in zip(x, y):
                if np.isfinite(yi):
                    per_frame[xi].append(yi)
        xs = sorted(per_frame)
        ax.plot(xs, [np.mean(per_frame[x]) for x in xs], lw=2.0, color="black", label="mean over tracks")
        ax.set_xlabel("frame")
        ax.set_ylabel(f"{'R_err' if key == 're_deg' else 'T_err'} [{unit}]")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(f"Tracking error over frames: {report.settings.get('estimator', '')}", fontsize=10)
    fig.tight_layout()
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=110)
    plt.close(fig)
    return buf.getvalue()


def write_tracking(report: TrackingReport, out: str | Path) -> dict[str, Path]:
    """Write ``tracking.csv``, ``tracking.md``, ``tracking.json`` and ``tracking.png`` into ``out``; returns
    their paths (keys ``tracking_frames``, ``tracking_table``, ``tracking_metrics``, ``tracking_plot``)."""
    out = Path(out)
    paths = {"tracking_frames": out / "tracking.csv", "tracking_table": out / "tracking.md",
             "tracking_metrics": out / "tracking.json", "tracking_plot": out / "tracking.png"}
    atomic_write_text(paths["tracking_frames"], csv_text(report.frames, FRAME_COLUMNS))
    atomic_write_text(paths["tracking_table"], tracking_table(report))
    atomic_write_text(paths["tracking_metrics"], json.dumps(report.to_json(), indent=2) + "\n")
    atomic_write_bytes(paths["tracking_plot"], _plot(report))
    return paths
