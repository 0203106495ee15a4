"""Where a run's estimates land, per target: right, on the object but off, on another object, or on clutter.

Reads a ``simtest eval`` run folder (``errors.csv`` and ``results.csv``) and the BOP dataset it ran on, with
visible masks (``simtest masks`` makes them for a real set). Each target of ``errors.csv`` is put in one bucket
by one estimate of its object in its image: of the estimates whose silhouette lies on the target's visible mask
the one that lies on it most, else the highest-scored (with one instance per object, as in LM-O, the one
``simtest eval`` matches):

* ``pass``: ADD(-S) within 0.1 of the diameter (``errors.csv``, as ``simtest eval`` scores it);
* ``on it, turned < 15``: at least :data:`ON_MASK` of the estimate's silhouette lies on the target's visible
  mask and the rotation error (over the object's symmetries) is below 15 degrees: the depth or the position is off;
* ``on it, turned``: on the target's visible mask, rotation error 15 degrees or more;
* ``on another object``: on another annotated object's visible mask instead;
* ``on clutter``: its silhouette is in the image, on neither;
* ``off the image`` / ``no estimate``.

For the ``on it, turned < 15`` and passing estimates of objects without symmetries it also prints the median of
the estimated over the true distance and the median image offset of the projected model origin (estimate minus
truth, pixels): a pipeline that fits the image without bias shows both near 1 and 0 on its own renders, so a
consistent offset on real frames is the offset between the annotations and the colour images. Run from the
repository root::

    simtest masks --data LMO --out LMO-masked
    python docs/sim2real_errors.py runs/lmo-default LMO-masked [--first-images 25]
    python docs/sim2real_errors.py runs/scored LMO-masked --results mine.csv   # after simtest eval --results mine.csv
"""

from __future__ import annotations

import argparse
import csv
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from simtest.camera import pinhole_pixels  # noqa: E402
from simtest.io import bop  # noqa: E402
from simtest.io.bop_results import read_bop_results  # noqa: E402
from simtest.io.bop_splits import dataset_split_dir, scene_dirs  # noqa: E402
from simtest.metrics.bop19 import ResultRow  # noqa: E402
from simtest.objects.loaders import load_dataset_objects  # noqa: E402
from simtest.render.silhouette import object_silhouette  # noqa: E402

#: Share of an estimate's silhouette that must lie on a visible mask for the estimate to be "on" that object.
ON_MASK = 0.3
#: Rotation error (degrees) below which an estimate on its object counts as turned right.
TURN_DEG = 15.0
BUCKETS = ("pass", "on it, turned < 15", "on it, turned", "on another object", "on clutter", "off the image",
           "no estimate")


def buckets(run: Path, data: Path, first_images: int | None = None, results: Path | None = None) -> dict:
    """``{"counts": {obj_id: {bucket: n}}, "near": [(distance ratio, du px, dv px)]}`` over
    the run's targets (its first ``first_images`` images by scene and image id, or all); ``results``: the
    estimates (default ``run/results.csv``; ``simtest eval --results`` scores a file it does not copy)."""
    objects = load_dataset_objects(data)
    scenes = {int(s.name): s for s in scene_dirs(dataset_split_dir(data))}
    annotations = {k: bop.read_scene(s) for k, s in scenes.items()}
    with open(run / "errors.csv", newline="") as f:
        targets = list(csv.DictReader(f))
    found: dict[tuple[int, int, int], list[ResultRow]] = defaultdict(list)
    for row in read_bop_results(results or run / "results.csv"):  # t in metres
        found[(row.scene_id, row.im_id, row.obj_id)].append(row)
    images = sorted({(int(r["scene_id"]), int(r["im_id"])) for r in targets})
    kept = set(images[:first_images] if first_images is not None else images)
    counts: dict[int, dict[str, int]] = defaultdict(lambda: dict.fromkeys(BUCKETS, 0))
    near = []
    masks: dict[tuple[int, int], list[np.ndarray]] = {}
    for t in targets:
        scene, im, gt_id, oid = int(t["scene_id"]), int(t["im_id"]), int(t["gt_id"]), int(t["obj_id"])
        if (scene, im) not in kept:
            continue
        rows = found.get((scene, im, oid), [])
        if not rows:
            counts[oid]["no estimate"] += 1
            continue
        d = annotations[scene][im]
        if (scene, im) not in masks:
            masks = {(scene, im): [bop.read_mask(scenes[scene], im, k) for k in range(len(d["gt"]))]}
        visible = masks[(scene, im)]
        H, W = visible[gt_id].shape
        posed = []
        for row in rows:
            R, tr = row.R, row.t
            sil = object_silhouette(objects.get(oid), R, tr, d["K"], W, H) if tr[2] > 0 else np.zeros((H, W), bool)
            on = [float((sil & m).sum()) / max(int(sil.sum()), 1) for m in visible]
            posed.append((on[gt_id] >= ON_MASK, on[gt_id], float(row.score), tr, sil, on))
        _, _, _, tr, sil, on = max(posed, key=lambda p: p[:3])
        passed = t["matched"] == "1" and float(t["add_s_or_add"]) < 0.1 * float(t["diameter_m"])
        turned = not (t["re_sym"] and float(t["re_sym"]) < TURN_DEG)
        if passed:
            bucket = "pass"
        elif on[gt_id] >= ON_MASK:
            bucket = "on it, turned" if turned else "on it, turned < 15"
        elif any(v >= ON_MASK for k, v in enumerate(on) if k != gt_id):
            bucket = "on another object"
        else:
            bucket = "on clutter" if sil.any() else "off the image"
        counts[oid][bucket] += 1
        if bucket in ("pass", "on it, turned < 15") and t["symmetric"] == "0":
            g = d["gt"][gt_id].T_cam_obj
            u, v = pinhole_pixels(d["K"], tr)
            ug, vg = pinhole_pixels(d["K"], g.t)
            near.append((float(np.linalg.norm(tr) / np.linalg.norm(g.t)), float(u - ug), float(v - vg)))
    return {"counts": dict(counts), "near": near}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", type=Path, help="a simtest eval run folder (errors.csv, results.csv)")
    ap.add_argument("data", type=Path, help="the BOP dataset it ran on, with mask_visib/")
    ap.add_argument("--first-images", type=int, default=None, help="only the run's first N images")
    ap.add_argument("--results", type=Path, default=None,
                    help="the estimates the run scored (default RUN/results.csv; for runs of simtest eval --results)")
    args = ap.parse_args()
    r = buckets(args.run, args.data, args.first_images, args.results)
    counts = r["counts"]
    print("| object | targets | " + " | ".join(BUCKETS) + " |")
    print("|---" * (len(BUCKETS) + 2) + "|")
    total = dict.fromkeys(BUCKETS, 0)
    for oid in sorted(counts):
        c = counts[oid]
        for b in BUCKETS:
            total[b] += c[b]
        print(f"| {oid} | {sum(c.values())} | " + " | ".join(str(c[b]) for b in BUCKETS) + " |")
    n = sum(total.values())
    print(f"| all | {n} | " + " | ".join(f"{total[b]} ({100 * total[b] / max(n, 1):.1f} %)" for b in BUCKETS) + " |")
    near = np.array(r["near"]).reshape(-1, 3)
    if len(near):
        q = np.percentile(near[:, 0], [25, 50, 75])
        print(f"\npassing or on it and turned < 15 (objects without symmetries, {len(near)} estimates): distance "
              f"estimated / true {q[1]:.4f} (quartiles {q[0]:.4f} - {q[2]:.4f}); image offset of the model "
              f"origin, estimate - truth: du {np.median(near[:, 1]):+.2f} px, dv {np.median(near[:, 2]):+.2f} px "
              f"(medians)")


if __name__ == "__main__":
    main()
