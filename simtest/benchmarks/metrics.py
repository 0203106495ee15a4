"""Timings of the metrics on a fixed synthetic model: ``simtest bench metrics``.

Model: a closed cylinder (radius 4 cm, height 12 cm) with 1499 sections = 3000 vertices, 5996 faces,
continuous symmetry about z (315 discrete steps, BOP discretisation). Poses 0.6 m in front of a
640 x 480 camera. The rasterizer is also timed on a 2000-face cylinder. Prints milliseconds per call
(best of ``--repeat`` runs of ``--number`` calls).
"""

from __future__ import annotations

import timeit

import numpy as np
import trimesh

from simtest.geometry import rotation_about
from simtest.metrics import (
    add,
    adi,
    chamfer_distance,
    iou_3d,
    mspd,
    mssd,
    re,
    te,
    vsd,
    ycb_auc,
)
from simtest.objects import ContinuousSymmetry, ObjectModel
from simtest.render.zbuffer import rasterize_depth, render_depth


def run(number: int = 5, repeat: int = 3) -> dict[str, float]:
    """Milliseconds per call of each metric (best of ``repeat``)."""
    mesh = trimesh.creation.cylinder(radius=0.04, height=0.12, sections=1499)
    obj = ObjectModel(1, "cyl", "can", 0, mesh, symmetries_continuous=(ContinuousSymmetry((0.0, 0.0, 1.0)),))
    pts = obj.vertices
    syms = obj.symmetry_transforms()
    K = np.array([[615.0, 0.0, 319.5], [0.0, 615.0, 239.5], [0.0, 0.0, 1.0]])
    R_g, t_g = rotation_about([1.0, 0.0, 0.0], 0.6), np.array([0.0, 0.0, 0.6])
    R_e, t_e = rotation_about([0.3, 1.0, 0.2], 0.2) @ R_g, t_g + [0.01, -0.005, 0.02]
    depth = render_depth(obj.vertices, obj.faces, R_g, t_g, K, 640, 480)
    small = trimesh.creation.cylinder(radius=0.04, height=0.12, sections=500)  # 2000 faces
    small_v = small.vertices @ R_g.T + t_g
    sRT1 = np.eye(4)
    sRT1[:3, :3], sRT1[:3, 3] = R_g, t_g
    sRT2 = np.eye(4)
    sRT2[:3, :3], sRT2[:3, 3] = R_e, t_e
    dists = np.random.default_rng(0).exponential(0.03, 10000)
    cases = {
        "add": lambda: add(R_e, t_e, R_g, t_g, pts),
        "adi (ADD-S)": lambda: adi(R_e, t_e, R_g, t_g, pts),
        "re": lambda: re(R_e, R_g),
        "te": lambda: te(t_e, t_g),
        "mssd (identity only)": lambda: mssd(R_e, t_e, R_g, t_g, pts),
        f"mssd ({len(syms)} symmetries)": lambda: mssd(R_e, t_e, R_g, t_g, pts, syms),
        f"mspd ({len(syms)} symmetries)": lambda: mspd(R_e, t_e, R_g, t_g, K, pts, syms, 640),
        "vsd 640x480 (10 taus, 2 renders)": lambda: vsd(R_e, t_e, R_g, t_g, depth, K, obj, 0.015,
                                                        np.arange(0.05, 0.51, 0.05), obj.diameter),
        "rasterize_depth 640x480, 2000 faces": lambda: rasterize_depth(small_v, small.faces, K, 640, 480),
        "rasterize_depth 640x480, 5996 faces": lambda: render_depth(obj.vertices, obj.faces, R_g, t_g, K, 640, 480),
        "iou_3d": lambda: iou_3d(sRT1, sRT2, (0.08, 0.08, 0.12), (0.08, 0.08, 0.12)),
        "iou_3d symmetric (20 rotations)": lambda: iou_3d(sRT1, sRT2, (0.08, 0.08, 0.12), (0.08, 0.08, 0.12),
                                                          symmetric=True),
        "chamfer_distance 3000 x 3000": lambda: chamfer_distance(pts, pts @ R_e.T),
        "ycb_auc (10000 distances)": lambda: ycb_auc(dists),
    }
    out = {}
    for name, fn in cases.items():
        fn()  # warm caches
        best = min(timeit.repeat(fn, number=number, repeat=repeat))
        out[name] = 1000.0 * best / number
    return out


def table(timings: dict[str, float]) -> str:
    """One line per metric: name and milliseconds per call."""
    return "\n".join(f"{name:40s} {ms:9.3f} ms" for name, ms in timings.items())
