"""How good are the outline network's masks on real frames, and what would exact ones be worth (docs/sim2real.md)?

Reads a run's kept poses (``RUN/results.csv`` of ``simtest eval``, before or after the outline fit) on a BOP
dataset with visible masks (``simtest masks`` makes them for a real set). For every pose whose silhouette lies
on its object (IoU >= 0.3 with the object's visible mask in the fit's crop), it reports the mean IoU with the
visible mask of the pose's own silhouette (the prior) and of each network's mask, per object. With
``--oracle OUT.csv`` it also writes the run's poses fitted as the outline stage fits them
(:func:`simtest.estimators.templates.outline.fit_to_mask` with its settings), but to the object's exact visible
mask instead of a network's (a pose of an object not in the image keeps its place): the most a perfect outline network could give these poses; score it with
``simtest eval --data DATA --results OUT.csv``. Run from the repository root::

    python docs/sim2real_outline.py runs/lmo-default LMO-masked \\
        --net simtest/estimators/weights/templates_outline_lmo_640x480.onnx --oracle runs/oracle.csv
"""

from __future__ import annotations

import argparse
import csv
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from simtest.estimators.templates.crops import mask_in_crop  # noqa: E402
from simtest.estimators.templates.outline import OutlineNet, fit_to_mask  # noqa: E402
from simtest.io import bop  # noqa: E402
from simtest.io.bop_splits import dataset_split_dir, scene_dirs  # noqa: E402
from simtest.objects.loaders import load_dataset_objects  # noqa: E402

ON_OBJECT_IOU = 0.3


def _iou(a: np.ndarray, b: np.ndarray) -> float:
    return float((a & b).sum() / max((a | b).sum(), 1))


def _pose(row: dict) -> tuple[np.ndarray, np.ndarray]:
    """A results.csv row's pose: R (3, 3), t (3,) in metres."""
    return np.array(row["R"].split(), float).reshape(3, 3), np.array(row["t"].split(), float) / 1000.0


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", type=Path, help="a simtest eval run folder (its results.csv)")
    ap.add_argument("data", type=Path, help="the BOP dataset it ran on, with mask_visib/")
    ap.add_argument("--net", action="append", default=[], help="outline network (.onnx or .pt); repeatable")
    ap.add_argument("--oracle", type=Path, help="write the poses fitted to the exact visible masks here")
    ap.add_argument("--size", type=int, default=128, help="crop side, pixels (the networks' input; default 128)")
    args = ap.parse_args()
    nets = [OutlineNet(p, "torch" if p.endswith(".pt") else "onnx") for p in args.net]
    objects = load_dataset_objects(args.data)
    scenes = {int(s.name): s for s in scene_dirs(dataset_split_dir(args.data))}
    annotations = {k: bop.read_scene(s) for k, s in scenes.items()}
    rows = list(csv.DictReader(open(args.run / "results.csv", newline="")))
    per_object: dict[int, list[list[float]]] = {}
    fitted = []
    for row in rows:
        scene, im, oid = int(row["scene_id"]), int(row["im_id"]), int(row["obj_id"])
        obj, (R, t) = objects.get(oid), _pose(row)
        d = annotations[scene][im]
        mine = [k for k, g in enumerate(d["gt"]) if g.obj_id == oid]
        rgb = bop.read_image(scenes[scene], im)
        visible = bop.read_mask(scenes[scene], im, mine[0], visible=True) if mine else None
        exact = (lambda crop: mask_in_crop(visible, d["K"], crop) > 0) if mine else None

        def measured(crop, exact=exact):
            """The exact mask in the fit's crop, after the priors' and networks' IoU with it (on-object poses)."""
            truth, prior = exact(crop), crop.mask > 0
            if _iou(prior, truth) >= ON_OBJECT_IOU:
                per_object.setdefault(oid, []).append([_iou(prior, truth)] + [
                    _iou(net.mask(crop.rgb, crop.mask), truth) for net in nets])
            return truth

        if exact is not None:  # a pose on another object than its own keeps its place
            fit = fit_to_mask(obj, rgb, d["K"], R, t, measured, args.size)  # the estimator's fit settings
            R, t = fit.R, fit.t
        fitted.append({**row, "R": " ".join(repr(float(v)) for v in R.reshape(-1)),
                       "t": " ".join(repr(float(v) * 1000.0) for v in t)})
    names = ["prior"] + [Path(p).name for p in args.net]
    print("mean IoU with the visible mask, poses on their object: " + ", ".join(names))
    for oid, values in sorted(per_object.items()):
        print(f"obj {oid:3d} ({len(values):4d} poses): " + "  ".join(f"{v:.3f}" for v in np.mean(values, 0)))
    every = np.concatenate([np.asarray(v) for v in per_object.values()]) if per_object else np.zeros((0, 1))
    print(f"all     ({len(every):4d} poses): " + "  ".join(f"{v:.3f}" for v in every.mean(0)))
    if args.oracle is not None:
        with open(args.oracle, "w", newline="") as f:
            w = csv.DictWriter(f, fieldnames=list(rows[0].keys()))
            w.writeheader()
            w.writerows(fitted)
        print(f"wrote {args.oracle}: score it with simtest eval --data {args.data} --results {args.oracle}")


if __name__ == "__main__":
    main()
