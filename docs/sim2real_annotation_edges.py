"""Do the annotated poses' outlines lie on the photographs' edges? The depth each annotated pose would need.

For every target at least ``--min-visible`` visible, the annotated pose is moved as the edge fit moves a pose
(:func:`simtest.estimators.templates.edges.fit_edges`: an image shift within ``--shift`` pixels and a depth
factor within ``1 +- --max-scale``, the rotation kept) until the model's outline lies on the image's Canny edges.
Per object it prints the median depth factor and its quartiles (below 1: the image's edges want the object
nearer than annotated), the outline's mean clipped edge distance before and after (pixels), the median shift,
and how many of the moved poses lie beyond 0.1 of the object's diameter from the annotated one (ADD of a pure
depth change ``|s - 1| |t|``; the shift is left out). On a simtest set, whose poses are exact, the factors show
the check's own noise; on real frames an object whose factor stays away from 1 has annotations (or a model)
that a method fitting the photograph cannot reproduce. Run from the repository root::

    python docs/sim2real_annotation_edges.py LMO
    python docs/sim2real_annotation_edges.py data/lmo-simtest4000 --json edges.json
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from simtest.estimators.templates.edges import edge_distance, fit_edges  # noqa: E402
from simtest.io import bop  # noqa: E402
from simtest.io.bop_splits import dataset_split_dir, scene_dirs  # noqa: E402
from simtest.objects.loaders import load_dataset_objects  # noqa: E402


def annotation_edges(data: Path, min_visible: float = 0.9, shift_px: float = 3.0, max_scale: float = 0.12,
                     max_images: int | None = None) -> list[dict]:
    """One record per target at least ``min_visible`` visible: its ids, the depth factor ``scale`` and shift
    ``du, dv`` (pixels) that put the annotated outline on the edges, the costs ``before`` and ``after``
    (pixels), the annotated distance ``distance_m`` and the object's ``diameter_m``."""
    objects = load_dataset_objects(data)
    out = []
    for scene in scene_dirs(dataset_split_dir(data)):
        annotations = bop.read_scene(scene)
        for im in sorted(annotations)[:max_images]:
            d, dist = annotations[im], None
            for k, g in enumerate(d["gt"]):
                if g.visib_fract < min_visible:
                    continue
                if dist is None:
                    dist = edge_distance(bop.read_image(scene, im))
                T, obj = g.T_cam_obj, objects.get(g.obj_id)
                f = fit_edges(obj, T.R, T.t, d["K"], dist, shift_px=shift_px, max_scale=max_scale, min_gain=0.0)
                out.append({"scene_id": int(scene.name), "im_id": int(im), "gt_id": k, "obj_id": int(g.obj_id),
                            "visib_fract": float(g.visib_fract), "scale": float(f.scale), "du": float(f.du),
                            "dv": float(f.dv), "before": float(f.cost_before), "after": float(f.cost_after),
                            "distance_m": float(np.linalg.norm(T.t)), "diameter_m": float(obj.diameter)})
    return out


def table(records: list[dict]) -> str:
    """Markdown table of :func:`annotation_edges`'s records by object."""
    lines = ["| object | targets | depth factor, median (quartiles) | edge distance before -> after, px | "
             "shift du, dv px | moved beyond 0.1 d |", "|---|---|---|---|---|---|"]
    for oid in sorted({r["obj_id"] for r in records}):
        rs = [r for r in records if r["obj_id"] == oid]
        s = np.array([r["scale"] for r in rs])
        q1, q2, q3 = np.percentile(s, [25, 50, 75])
        beyond = sum(abs(r["scale"] - 1.0) * r["distance_m"] > 0.1 * r["diameter_m"] for r in rs)
        lines.append(f"| {oid} | {len(rs)} | {q2:.3f} ({q1:.3f}-{q3:.3f}) | "
                     f"{np.median([r['before'] for r in rs]):.2f} -> {np.median([r['after'] for r in rs]):.2f} | "
                     f"{np.median([r['du'] for r in rs]):+.2f}, {np.median([r['dv'] for r in rs]):+.2f} | "
                     f"{beyond} ({100 * beyond / len(rs):.0f} %) |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("data", type=Path, help="a BOP dataset folder (real or simtest-generated)")
    ap.add_argument("--min-visible", type=float, default=0.9, help="least visible fraction (default 0.9)")
    ap.add_argument("--shift", type=float, default=3.0, help="largest image shift, pixels (default 3)")
    ap.add_argument("--max-scale", type=float, default=0.12, help="largest relative depth change (default 0.12)")
    ap.add_argument("--max-images", type=int, default=None, help="only the first N images of each scene")
    ap.add_argument("--json", type=Path, default=None, help="also write the per-target records here")
    args = ap.parse_args()
    records = annotation_edges(args.data, args.min_visible, args.shift, args.max_scale, args.max_images)
    if args.json:
        args.json.write_text(json.dumps(records, indent=1))
    print(table(records))


if __name__ == "__main__":
    main()
