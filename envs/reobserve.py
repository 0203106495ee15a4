"""Re-observation on the way to the grasp: when to look again, how a new look updates the pose, the stage table.

One observation from the observation pose (0.42 m away) is all a plain episode sees; then the arm moves blind.
With re-observation (:func:`simtest.envs.episode.run_episode`'s ``reobserve``) the wrist camera captures again
on the way in, where it is closer and sees the object larger:

* ``"none"``: no re-observation (the plain episode);
* ``"pregrasp"``: once at the pre-grasp pose;
* ``"approach:K"``: ``K`` times on the straight way from the observation pose to above the pre-grasp pose (at
  fractions ``k / (K + 1)`` of it, the camera turning from the observation view toward the grasp's), then once
  at the pre-grasp pose.

Each new capture is an observation of its own (``Observation.im_id`` = its stage index, so the ``oracle``'s
noise is drawn anew per observation). The pose is updated (:data:`UPDATES`) by the estimator again
(``"estimate"``) or by a tracker warm-started from the pose so far (``"track"``: the estimator's own
``track(observation, prior)`` when it offers one, else :class:`~simtest.estimators.track_icp.TrackICPEstimator`
started at the prior), and combined with the earlier looks (:data:`FUSIONS`): ``"mean"`` averages every look
in the world frame (the object does not move before the gripper touches it; each look's rotation is first
turned by the object symmetry nearest the running mean, so a symmetric object's equivalent answers do not
cancel), ``"latest"`` keeps only the newest look, ``"gated"`` averages like ``"mean"`` but leaves out a look
that disagrees with the pose so far by more than :data:`GATE_TRANSLATION` or :data:`GATE_ROTATION` (the
first look, from farther away, sees the whole object; a close look can be ambiguous). The grasp is planned
again from the updated pose and the new plan is taken when it moved (:data:`REPLAN_TRANSLATION`,
:data:`REPLAN_ROTATION`).

Every look is a *stage* (``first``, ``approach 1`` .. ``approach K``, ``pregrasp``): its pose errors against the
ground truth at that moment (the look's own estimate and the pose used after it) make the per-stage error
table (:func:`stage_table`). Units: metres, degrees.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
from scipy.spatial.transform import Rotation, Slerp

from simtest.errors import ConfigError
from simtest.geometry import Pose

__all__ = ["ReobserveSpec", "parse_reobserve", "UPDATES", "FUSIONS", "REPLAN_TRANSLATION", "REPLAN_ROTATION",
           "GATE_TRANSLATION", "GATE_ROTATION", "PoseFusion", "plan_moved", "waypoint", "stage_table",
           "stage_markdown", "STAGE_COLUMNS"]

#: How a re-observation updates the pose (see the module docstring).
UPDATES = ("estimate", "track")
#: How the looks are combined (see the module docstring).
FUSIONS = ("mean", "latest", "gated")
#: ``"gated"`` fusion: a look farther than this from the pose so far (m, and radians after symmetry alignment)
#: is left out of the mean.
GATE_TRANSLATION = 0.025
GATE_ROTATION = np.deg2rad(25.0)
#: A re-planned grasp is taken when its grasp pose moved more than this (m) ...
REPLAN_TRANSLATION = 0.003
#: ... or turned more than this (rad).
REPLAN_ROTATION = np.deg2rad(3.0)
#: Columns of ``stages.csv`` (one row per look of an episode; m, deg).
STAGE_COLUMNS = ["episode", "seed", "target_name", "stage", "found", "add_s", "re_sym_deg", "te", "used_add_s",
                 "used_re_sym_deg", "used_te", "replanned", "visible_pixels", "estimate_s"]


@dataclass(frozen=True)
class ReobserveSpec:
    """When an episode looks again.

    Attributes:
        approach: Looks on the way from the observation pose to above the pre-grasp pose (``K``).
        pregrasp: Whether to look at the pre-grasp pose.
    """

    approach: int = 0
    pregrasp: bool = False

    @property
    def active(self) -> bool:
        """Whether any re-observation happens."""
        return self.pregrasp or self.approach > 0

    def stages(self) -> list[tuple[str, float]]:
        """The re-observation stages as ``(name, fraction)``: fraction of the way to above the pre-grasp pose
        (< 1), or 1.0 for the pre-grasp pose itself."""
        out = [(f"approach {k}", k / (self.approach + 1)) for k in range(1, self.approach + 1)]
        return out + ([("pregrasp", 1.0)] if self.pregrasp else [])

    def __str__(self) -> str:
        return "none" if not self.active else ("pregrasp" if not self.approach else f"approach:{self.approach}")


def parse_reobserve(text: Any) -> ReobserveSpec:
    """``"none"``, ``"pregrasp"`` or ``"approach:K"`` (K >= 1 looks on the way, then one at the pre-grasp pose).

    Raises:
        ConfigError: Anything else (the message names the bad value and the forms).
    """
    if isinstance(text, ReobserveSpec):
        return text
    s = str(text).strip().lower() if text is not None else "none"
    if s == "none":
        return ReobserveSpec()
    if s == "pregrasp":
        return ReobserveSpec(pregrasp=True)
    if s.startswith("approach:") and s[9:].isdigit() and 1 <= int(s[9:]) <= 20:
        return ReobserveSpec(approach=int(s[9:]), pregrasp=True)
    raise ConfigError(f"reobserve must be 'none', 'pregrasp' or 'approach:K' with K in 1..20, got {text!r}")


def check_choice(name: str, value: Any, allowed: Sequence[str]) -> str:
    """``value`` if it is one of ``allowed``.

    Raises:
        ConfigError: Naming the field, the bad value and the allowed ones.
    """
    if value not in allowed:
        raise ConfigError(f"{name} must be one of {', '.join(allowed)}, got {value!r}")
    return value


class PoseFusion:
    """The running world pose of the target from one or more looks (see the module docstring).

    Args:
        first: The first look's ``T_world_obj`` (m).
        symmetries: The object's symmetry transforms (S, 4, 4), identity first.
        mode: One of :data:`FUSIONS`.
    """

    def __init__(self, first: Pose, symmetries: np.ndarray, mode: str = "mean") -> None:
        self.mode = check_choice("reobserve fusion", mode, FUSIONS)
        self.syms = np.asarray(symmetries, dtype=np.float64).reshape(-1, 4, 4)
        self.looks: list[np.ndarray] = [first.matrix()]
        self.pose = first

    def add(self, look: Pose) -> Pose:
        """Take a new look (``T_world_obj``, m) and return the updated pose."""
        T = look.matrix()
        if self.mode == "latest":
            self.looks = [T]
            self.pose = look
            return look
        cands = T[None] @ self.syms  # the same physical pose under every symmetry
        R_ref = self.pose.R
        cos = (np.einsum("nij,ij->n", cands[:, :3, :3], R_ref) - 1.0) / 2.0
        best = int(np.argmax(cos))
        if self.mode == "gated":
            far = float(np.linalg.norm(cands[best, :3, 3] - self.pose.t)) > GATE_TRANSLATION
            if far or float(np.arccos(np.clip(cos[best], -1.0, 1.0))) > GATE_ROTATION:
                return self.pose  # left out: not in ``looks``
        self.looks.append(cands[best])
        Ts = np.stack(self.looks)
        U, _, Vt = np.linalg.svd(Ts[:, :3, :3].sum(axis=0))  # chordal L2 mean of the rotations
        R = U @ np.diag([1.0, 1.0, np.linalg.det(U @ Vt)]) @ Vt
        self.pose = Pose(R, Ts[:, :3, 3].mean(axis=0))
        return self.pose


def plan_moved(old, new) -> bool:
    """Whether the grasp of plan ``new`` lies more than :data:`REPLAN_TRANSLATION` m or :data:`REPLAN_ROTATION`
    rad from that of ``old`` (or is another candidate)."""
    if old.index != new.index or old.flipped != new.flipped:
        return True
    dt = float(np.linalg.norm(new.grasp.t - old.grasp.t))
    c = (float(np.trace(old.grasp.R.T @ new.grasp.R)) - 1.0) / 2.0
    return dt > REPLAN_TRANSLATION or float(np.arccos(np.clip(c, -1.0, 1.0))) > REPLAN_ROTATION


def waypoint(start: Pose, goal: Pose, fraction: float) -> Pose:
    """The TCP pose ``fraction`` (0..1) of the way from ``start`` to ``goal``: straight in position, slerp in
    orientation."""
    f = float(np.clip(fraction, 0.0, 1.0))
    rots = Rotation.from_matrix(np.stack([start.R, goal.R]))
    R = Slerp([0.0, 1.0], rots)([f]).as_matrix()[0]
    return Pose(R, (1.0 - f) * np.asarray(start.t) + f * np.asarray(goal.t))


def _median(values: list) -> float | None:
    v = np.asarray([x for x in values if x is not None and np.isfinite(x)], dtype=np.float64)
    return float(np.median(v)) if len(v) else None


def stage_table(rows: list[dict]) -> list[dict]:
    """Per stage (in the order they occur): looks, looks with an estimate, and the median errors of the look's
    own estimate and of the pose used after it (m, deg), over the stage rows of a run (:data:`STAGE_COLUMNS`)."""
    order: list[str] = []
    groups: dict[str, list[dict]] = {}
    for r in rows:
        if r["stage"] not in groups:
            order.append(r["stage"])
            groups[r["stage"]] = []
        groups[r["stage"]].append(r)
    order.sort(key=lambda s: (s != "first", s == "pregrasp", s))
    out = []
    for s in order:
        g = groups[s]
        out.append({"stage": s, "looks": len(g), "found": sum(bool(r["found"]) for r in g),
                    "replanned": sum(bool(r["replanned"]) for r in g),
                    **{f"median_{k}": _median([r[k] for r in g])
                       for k in ("add_s", "re_sym_deg", "te", "used_add_s", "used_re_sym_deg", "used_te")}})
    return out


def stage_markdown(table: list[dict]) -> str:
    """:func:`stage_table` as a Markdown table (millimetres, degrees)."""
    def f(v: float | None, scale: float = 1.0) -> str:
        return "-" if v is None else f"{v * scale:.1f}"

    lines = ["| stage | looks | estimates | re-planned | ADD(-S) mm | re_sym deg | te mm | used ADD(-S) mm | "
             "used re_sym deg | used te mm |", "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|"]
    for e in table:
        lines.append(f"| {e['stage']} | {e['looks']} | {e['found']} | {e['replanned']} | "
                     f"{f(e['median_add_s'], 1000)} | {f(e['median_re_sym_deg'])} | {f(e['median_te'], 1000)} | "
                     f"{f(e['median_used_add_s'], 1000)} | {f(e['median_used_re_sym_deg'])} | "
                     f"{f(e['median_used_te'], 1000)} |")
    return "\n".join(lines) + "\n"
