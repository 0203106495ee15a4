"""The metric registry: every aggregate metric declared once (key, label, definition, direction, format).

Evaluation tables (:mod:`simtest.evaluation.tables`, :mod:`simtest.evaluation.tracking`), ``metrics.json`` definitions, sweep
configs (which metrics to tabulate), sweep tables and the HTML report all read this table, so a new metric is added here and in the code
that computes it (:func:`simtest.evaluation.scoring.aggregate` or the BOP19 evaluation), nowhere else.

Values are stored in SI units or fractions (metres, degrees where the key says ``_deg``, seconds, fractions
in [0, 1]); ``scale`` and ``unit`` say how they are shown (e.g. a fraction as percent).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from simtest.metrics.auc import ADDS_2CM, YCB_AUC_MAX_THRESHOLD

__all__ = ["Metric", "METRICS", "metric", "metric_keys", "definitions", "NDEG_MCM"]

#: (degrees, centimetres) pairs of the n deg m cm accuracies.
NDEG_MCM: tuple[tuple[float, float], ...] = ((5, 2), (5, 5), (10, 2), (10, 5))


@dataclass(frozen=True)
class Metric:
    """One aggregate metric.

    Attributes:
        key: Key in an evaluation's ``overall`` / ``per_object`` dicts (and ``metrics.json``).
        label: Short label for table headers and plot axes.
        definition: One sentence: what is measured, over what, with which threshold.
        scale: Multiplier from the stored value to the shown one (100 for a fraction shown in percent).
        unit: Unit of the shown value (``"%"``, ``"deg"``, ``"cm"``, ``"s"``, or ``""`` for counts).
        higher_is_better: Direction (``None`` for counts and timings, which have none).
        digits: Decimals shown.
        sweepable: Whether a sweep may tabulate it (pose-accuracy metrics, not counts).
        task: ``"detection"`` for the metrics only the detection task computes (BOP24 AP, classification;
            :mod:`simtest.evaluation.detection`), ``None`` for the others.
    """

    key: str
    label: str
    definition: str
    scale: float = 100.0
    unit: str = "%"
    higher_is_better: bool | None = True
    digits: int = 1
    sweepable: bool = True
    task: str | None = None

    def shown(self, value: float) -> float:
        """``value`` in display units."""
        return float(value) * self.scale

    def format(self, value: float | None, digits: int | None = None) -> str:
        """``value`` in display units as text: ``"inf"`` for +inf, an en dash for NaN or missing."""
        if value is None:
            return "–"
        v = float(value)
        if v == math.inf:
            return "inf"
        if not math.isfinite(v):
            return "–"
        d = self.digits if digits is None else digits
        return f"{v * self.scale:.{d}f}" if self.unit else f"{v:.0f}" if v == int(v) else f"{v:.{d}f}"

    @property
    def header(self) -> str:
        """``label [unit]`` (the unit omitted for counts)."""
        return f"{self.label} [{self.unit}]" if self.unit else self.label


def _ndeg(nd: float, mc: float) -> Metric:
    return Metric(f"{nd:g}deg{mc:g}cm", f"{nd:g}°{mc:g}cm",
                  f"fraction of targets with re_sym <= {nd:g} degrees and te <= {mc:g} cm (inclusive)")


#: Every aggregate metric, in the order tables show them.
METRICS: tuple[Metric, ...] = (
    Metric("num_targets", "N", "ground-truth instances with visib_fract >= 0.1 (BOP19 targets)", 1.0, "", None,
           sweepable=False),
    Metric("num_objects", "objects", "objects of the category with targets in the evaluated images", 1.0, "",
           None, sweepable=False),
    Metric("num_matched", "matched", "targets with an estimate assigned by the matching", 1.0, "", None,
           sweepable=False),
    Metric("add_s_or_add_01d", "ADD(-S)-0.1d",
           "fraction of targets with ADD(-S) < 0.1 x diameter (ADD-S for symmetric objects, else ADD)"),
    Metric("auc_adds", "AUC ADD-S",
           f"YCB-Video VOC-style area under the ADD-S accuracy curve, 0 to {YCB_AUC_MAX_THRESHOLD} m"),
    Metric("auc_add_s_or_add", "AUC ADD(-S)",
           f"YCB-Video VOC-style area under the ADD(-S) accuracy curve, 0 to {YCB_AUC_MAX_THRESHOLD} m"),
    Metric("adds_lt_2cm", "ADD-S<2cm", f"fraction of targets with ADD-S < {ADDS_2CM} m"),
    Metric("acc_pi_6", "Acc@π/6", "viewpoint protocol: fraction with re_sym < pi/6 (misses count as pi)"),
    Metric("acc_pi_18", "Acc@π/18", "viewpoint protocol: fraction with re_sym < pi/18 (misses count as pi)"),
    Metric("median_re_deg", "MedErr", "median rotation error re_sym over targets (misses count as 180 deg)",
           1.0, "deg", False),
    Metric("median_te_m", "Med te", "median translation error over targets (misses count as inf)", 100.0, "cm",
           False, digits=2),
    Metric("mean_add_s_or_add_m", "mean ADD(-S)", "mean ADD(-S) over matched targets", 100.0, "cm", False,
           digits=2),
    *(_ndeg(nd, mc) for nd, mc in NDEG_MCM),
    Metric("ar", "AR", "BOP19 Average Recall: mean of the evaluated AR_VSD, AR_MSSD, AR_MSPD (without VSD the "
           "mean of AR_MSSD and AR_MSPD)"),
    Metric("ar_vsd", "AR_VSD", "BOP19 recall of VSD (delta 15 mm, taus 0.05..0.5 x diameter, thresholds "
           "0.05..0.5) averaged over thresholds"),
    Metric("ar_mssd", "AR_MSSD", "BOP19 recall of MSSD at 0.05..0.5 x diameter, averaged over thresholds"),
    Metric("ar_mspd", "AR_MSPD", "BOP19 recall of MSPD at 5..50 px (scaled to a 640 px wide image), averaged over "
           "thresholds"),
    Metric("grasp_tolerance", "Grasp-ready", "fraction of targets whose estimate lies within the object's "
           "measured grasp tolerance on every axis (simtest tolerance map: the largest error along each axis "
           "keeping Panda grasp success >= 90 %); targets of objects the map covers; misses count as not ready",
           sweepable=False),
    Metric("num_grasp_targets", "grasp targets", "targets scored by grasp_tolerance (objects in the map)", 1.0,
           "", None, sweepable=False),
    Metric("num_images", "images", "images evaluated", 1.0, "", None, sweepable=False),
    Metric("num_estimates", "estimates", "valid pose estimates returned by the estimator", 1.0, "", None,
           sweepable=False),
    Metric("num_failures", "failures", "failures recorded in failures.csv (exceptions, timeouts, invalid or "
           "missing estimates)", 1.0, "", None, sweepable=False),
    Metric("num_image_exceptions", "image exceptions", "images on which the estimator raised", 1.0, "", None,
           sweepable=False),
    Metric("mean_time_per_image_s", "time/image", "mean wall time of estimate() per image", 1.0, "s", None,
           digits=4, sweepable=False),
    Metric("median_time_per_image_s", "median time/image", "median wall time of estimate() per image", 1.0, "s",
           None, digits=4, sweepable=False),
    # Tracking (simtest.evaluation.tracking): pooled over the target-frames of sequences, or averaged over tracks.
    *(Metric(f"iou{round(th * 100):d}", f"IoU{round(th * 100):d}",
             f"tracking: fraction of target-frames whose 3D IoU of the model's bounding box at the estimated and "
             f"ground-truth pose is >= {th:g} (misses count as 0)", sweepable=False) for th in (0.25, 0.5, 0.75)),
    Metric("mean_iou", "mean IoU", "tracking: mean 3D bounding-box IoU over target-frames (misses count as 0)",
           sweepable=False),
    Metric("mean_re_deg", "R_err", "tracking: mean rotation error re_sym over target-frames with an estimate", 1.0,
           "deg", False, digits=2, sweepable=False),
    Metric("mean_te_m", "T_err", "tracking: mean translation error over target-frames with an estimate", 100.0,
           "cm", False, digits=2, sweepable=False),
    Metric("tracked_fraction", "tracked", "tracking: mean over tracks of the fraction of the track's frames before "
           "its first loss (no estimate, re_sym > 10 deg or te > 5 cm)", sweepable=False),
    Metric("num_tracks", "tracks", "tracking: object instances followed through a sequence", 1.0, "", None,
           sweepable=False),
    # The detection task (simtest.evaluation.detection, simtest.metrics.bop24): nothing told about the image.
    Metric("ap", "AP", "BOP24 detection AP: mean of AP_MSSD and AP_MSPD", task="detection"),
    Metric("ap_mssd", "AP_MSSD", "BOP24: COCO-style AP (101 recall points) of MSSD at 0.05..0.5 x diameter, "
           "averaged over thresholds, then objects; instances with visib_fract < 0.1 ignored, at most 100 "
           "estimates per image", task="detection"),
    Metric("ap_mspd", "AP_MSPD", "BOP24: COCO-style AP of MSPD at 5..50 px (640 px wide image), averaged over "
           "thresholds, then objects", task="detection"),
    Metric("ap_mssd_mm", "AP_MSSD(mm)", "BOP24: COCO-style AP of MSSD at 2..20 mm, averaged over thresholds, "
           "then objects", task="detection"),
    Metric("num_gt_visible", "GT", "ground-truth instances with visib_fract >= 0.1 counted by the AP", 1.0, "",
           None, sweepable=False, task="detection"),
    Metric("cls_acc", "Cls", "top-1 classification accuracy: fraction of targets whose class-agnostic match "
           "(nearest estimate centre within half the diameter, by decreasing score) has the target's category; "
           "unmatched targets count as wrong", task="detection"),
    Metric("cls_acc_pi_6", "Cls Acc@π/6", "fraction of targets classified correctly with re_sym < pi/6",
           task="detection"),
    Metric("cls_acc_pi_18", "Cls Acc@π/18", "fraction of targets classified correctly with re_sym < pi/18",
           task="detection"),
    Metric("cls_median_re_deg", "Cls MedErr", "median re_sym over targets, 180 deg unless classified correctly",
           1.0, "deg", False, task="detection"),
)

_BY_KEY = {m.key: m for m in METRICS}


def metric(key: str) -> Metric:
    """The metric registered under ``key``.

    Raises:
        KeyError: Unknown key (the message lists the registered ones).
    """
    try:
        return _BY_KEY[key]
    except KeyError:
        raise KeyError(f"unknown metric {key!r}; registered: {', '.join(_BY_KEY)}") from None


def metric_keys(*, sweepable: bool | None = None) -> tuple[str, ...]:
    """Registered keys in table order; ``sweepable=True`` keeps the pose-accuracy metrics a sweep can show."""
    return tuple(m.key for m in METRICS if sweepable is None or m.sweepable == sweepable)


def definitions(task: str | None = None) -> dict[str, str]:
    """``{key: definition}`` plus the protocol notes, as written into ``metrics.json``: of every metric
    (``task=None``), of those a ``"localization"`` run computes, or of those of a ``"detection"`` run (all)."""
    out = {
        "targets": "ground-truth instances with visib_fract >= 0.1; a target without a matched estimate is a miss "
                   "(distance inf, rotation error pi)",
        "matching": "per image and object, estimates by decreasing score take the unassigned target with the "
                    "nearest translation",
        "units": "distances in metres (keys ending _m), angles in degrees (_deg), time in seconds (_s), other "
                 "accuracies as fractions in [0, 1]",
    }
    out.update({m.key: m.definition for m in METRICS if task != "localization" or m.task is None})
    return out
