"""Grasp success of the ``oracle`` against pose errors of exact size: a translation curve and a rotation curve
(the command behind the "Success against pose error" table of ``docs/grasping.md``; per-axis, per-object maps
are :mod:`simtest.envs.tolerance`).

Units: translation errors in millimetres, rotation errors in degrees (as the oracle's options take them).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Sequence

from simtest.envs.runner import GraspRunConfig, run_grasp_episodes
from simtest.envs.summary import percent

__all__ = ["NoiseSweepResult", "noise_sweep"]


@dataclass
class NoiseSweepResult:
    """Success against oracle pose error: one row per (translation mm, rotation deg) point."""

    rows: list[dict]
    episodes_per_point: int

    def table(self) -> str:
        """Markdown: translation error (mm), rotation error (deg), success with 95 % Wilson CI, and the
        most common failure reasons."""
        lines = ["| translation error mm | rotation error deg | success | 95% CI | failures |",
                 "|---:|---:|---:|---|---|"]
        for r in self.rows:
            fails = ", ".join(f"{k} {v}" for k, v in sorted(r["by_reason"].items(), key=lambda kv: -kv[1])
                              if k != "none" and v)
            lines.append(f"| {r['trans_mm']:g} | {r['rot_deg']:g} | {r['successes']}/{r['episodes']} = "
                         f"{percent(r['success_rate'])} | {percent(r['ci95'][0])} - {percent(r['ci95'][1])} | "
                         f"{fails or '-'} |")
        return "\n".join(lines) + "\n"


def noise_sweep(trans_mm: Sequence[float] = (0, 5, 10, 20, 30), rot_deg: Sequence[float] = (0, 5, 10, 20, 30), *,
                episodes: int = 27, seed: int = 0, objects: str = "builtin", targets: tuple = ("all",),
                n_distractors: int = 0, width: int = 160, height: int = 120, workers: int = 1,
                progress: bool = True, out_dir: str | Path | None = None) -> NoiseSweepResult:
    """Grasp success of the ``oracle`` with pose errors of exact size: two curves, translation error (rotation
    0) and rotation error (translation 0).

    The oracle runs in ``"fixed"`` mode: every estimate is off by exactly ``trans_mm`` millimetres in a random
    direction and ``rot_deg`` degrees about a random axis (seeded per episode). Every point uses the same
    episodes (same seeds, scenes and targets), so the curves are paired comparisons.

    Args:
        trans_mm: Translation errors, millimetres (run with zero rotation error).
        rot_deg: Rotation errors, degrees (run with zero translation error).
        episodes: Episodes per point.
        seed, objects, targets, n_distractors, width, height, workers: As in :class:`GraspRunConfig`.
        out_dir: If given, each point's outputs go to ``out_dir/t<mm>_r<deg>/`` and the table to
            ``out_dir/noise_sweep.md``.
    """
    points = [(float(t), 0.0) for t in trans_mm] + [(0.0, float(r)) for r in rot_deg if float(r) != 0.0
                                                    or not any(float(t) == 0.0 for t in trans_mm)]
    rows = []
    for t, r in points:
        cfg = GraspRunConfig(estimator="oracle", estimator_options={"trans_noise_mm": t, "rot_noise_deg": r,
                                                                   "rot_noise_mode": "fixed"},
                             episodes=episodes, seed=seed, objects=objects, targets=tuple(targets),
                             n_distractors=n_distractors, width=width, height=height, workers=workers)
        sub = None if out_dir is None else Path(out_dir) / f"t{t:g}_r{r:g}"
        rep = run_grasp_episodes(cfg, sub, progress=progress)
        s = rep.summary
        rows.append({"trans_mm": t, "rot_deg": r, "episodes": s["episodes"], "successes": s["successes"],
                     "success_rate": s["success_rate"], "ci95": s["ci95"], "by_reason": s["by_reason"]})
    result = NoiseSweepResult(rows, episodes)
    if out_dir is not None:
        Path(out_dir).mkdir(parents=True, exist_ok=True)
        (Path(out_dir) / "noise_sweep.md").write_text(result.table(), encoding="utf-8")
    return result
