"""Pose-estimation metrics. Metres and radians inside; each function states its units.

* :mod:`.pose` — instance level (BOP toolkit): ADD, ADD-S, re/te, MSSD, MSPD, VSD, ADD(-S)-0.1d.
* :mod:`.auc` — YCB-Video ADD(-S) AUC (VOC-style rule, threshold 0.10 m) and ADD-S < 2 cm.
* :mod:`.bop19` — BOP19 matching, recalls and Average Recall.
* :mod:`.nocs` — category level (NOCS): rotation / translation errors, n deg m cm, oriented-box 3D IoU,
  Chamfer distance.
* :mod:`.viewpoint` — viewpoint protocol: geodesic error, Acc@pi/6, Acc@pi/18, median error, and the
  (azimuth, elevation, theta) parameterisation.
* :mod:`.registry` — every aggregate metric declared once (key, label, definition, direction, format); tables,
  sweeps and reports read it.
"""

from simtest.metrics.auc import accuracy_below, auc_mean_rule, ycb_auc
from simtest.metrics.bop19 import (
    Bop19Result,
    EvalImage,
    GroundTruthPose,
    ResultRow,
    evaluate_bop19,
    match_greedy,
)
from simtest.metrics.nocs import (
    chamfer_distance,
    iou_3d,
    iou_3d_legacy,
    iou_accuracy,
    n_deg_m_cm,
    n_deg_m_cm_accuracy,
    rotation_error,
    rotation_error_deg,
    translation_error_cm,
)
from simtest.metrics.pose import (
    add,
    add_01d,
    add_s,
    add_s_or_add,
    adi,
    mspd,
    mssd,
    re,
    rotation_error_rad,
    te,
    vsd,
    vsd_from_depth,
)
from simtest.metrics.viewpoint import (
    accuracy_at,
    geodesic_error,
    median_error_deg,
    pose_to_viewpoint,
    rotation_errors,
    rotation_to_viewpoint,
    viewpoint_summary,
    viewpoint_to_pose,
    viewpoint_to_rotation,
)

__all__ = [
    # pose
    "add", "adi", "add_s", "re", "rotation_error_rad", "te", "mssd", "mspd", "vsd", "vsd_from_depth",
    "add_s_or_add", "add_01d",
    # auc
    "ycb_auc", "auc_mean_rule", "accuracy_below",
    # bop19
    "ResultRow", "GroundTruthPose", "EvalImage", "Bop19Result", "evaluate_bop19", "match_greedy",
    # nocs
    "rotation_error", "rotation_error_deg", "translation_error_cm", "n_deg_m_cm", "n_deg_m_cm_accuracy",
    "iou_3d", "iou_3d_legacy", "iou_accuracy", "chamfer_distance",
    # viewpoint
    "geodesic_error", "rotation_errors", "accuracy_at", "median_error_deg", "viewpoint_summary",
    "viewpoint_to_rotation", "rotation_to_viewpoint", "viewpoint_to_pose", "pose_to_viewpoint",
]
