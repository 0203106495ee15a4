"""Fit a run's kept poses afterwards, as the outline stage fits them, with an outline network of your choice.

The outline fit acts on the template estimator's kept poses only, so a change to the network (another file, or
several joined by ``+``, their probabilities averaged) can be scored without running the whole pipeline again:
take a run made without the fit (``simtest eval ... --opt outline=false``), fit its poses here with the stage's
shipped settings (LM-O's: the probability averaged with its mirror image's, temperature 2, depth within 10 %,
2-degree turns; ``simtest.estimators.keypoints.template_stage``) and score the file with
``simtest eval --data DATA --results OUT.csv``. With the shipped network this gives the pipeline's own poses
(docs/sim2real.md, fifteenth round). Optionally the pixels of the image's other kept poses that lie nearer the
camera (by their rendered depths) are left out of the fit (``--occluders``). Run from the repository root::

    python docs/sim2real_refit.py runs/lmo-nofit LMO --out runs/refit.csv \\
        --net simtest/estimators/weights/templates_outline_lmo_640x480.onnx+runs/outlines-s1/model.onnx
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import replace
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from simtest.estimators.keypoints.template_stage import (  # noqa: E402
    TEMPLATE_OUTLINE_MASK, TEMPLATE_OUTLINE_TEMPERATURE)
from simtest.estimators.templates import outline as outline_stage  # noqa: E402
from simtest.io import bop  # noqa: E402
from simtest.io.bop_results import read_bop_results, write_bop_results  # noqa: E402
from simtest.io.bop_splits import dataset_split_dir, scene_dirs  # noqa: E402
from simtest.objects.loaders import load_dataset_objects  # noqa: E402
from simtest.render.zbuffer import render_depth  # noqa: E402



def _fit_defaults() -> tuple[float, float]:
    """The template estimator's defaults for the fit: ``outline_max_scale``, ``outline_deg`` (degrees)."""
    import inspect

    from simtest.estimators.templates.estimator import TemplateEstimator

    p = inspect.signature(TemplateEstimator).parameters
    return float(p["outline_max_scale"].default), float(p["outline_deg"].default)


MAX_SCALE, STEP_DEG = _fit_defaults()


def nearer_pixels(depths: list[np.ndarray], i: int, z_origin: float) -> np.ndarray:
    """(H, W) bool: where another pose's rendered depth (metres, 0: empty) lies nearer than pose ``i``'s own
    (where ``i`` has none: than its origin's depth ``z_origin``)."""
    ref = np.where(depths[i] > 0, depths[i], z_origin)
    out = np.zeros(depths[i].shape, bool)
    for j, d in enumerate(depths):
        if j != i:
            out |= (d > 0) & (d < ref)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", type=Path, help="a simtest eval run folder (its results.csv), made without the fit")
    ap.add_argument("data", type=Path, help="the BOP dataset it ran on")
    ap.add_argument("--net", required=True, help="outline network(s): FILE or FILE+FILE+... (averaged)")
    ap.add_argument("--out", type=Path, required=True, help="the fitted poses, a BOP results CSV")
    ap.add_argument("--occluders", action="store_true", help="leave out pixels of nearer kept poses")
    ap.add_argument("--overwrite", action="store_true", help="replace --out if it exists")
    args = ap.parse_args()
    if args.out.exists() and not args.overwrite:
        sys.exit(f"{args.out} exists; pass --overwrite to replace it")
    net = outline_stage.load_outline(args.net)

    def read(crop):
        """The network's mask as the stage reads it (:func:`outline_stage.outline_fit`)."""
        return net.read(crop.rgb, crop.mask, TEMPLATE_OUTLINE_MASK, TEMPLATE_OUTLINE_TEMPERATURE)

    objects = load_dataset_objects(args.data)
    scenes = {int(s.name): s for s in scene_dirs(dataset_split_dir(args.data))}
    annotations = {k: bop.read_scene(s) for k, s in scenes.items()}
    rows = read_bop_results(args.run / "results.csv")  # t in metres
    images: dict[tuple[int, int], list[int]] = {}
    for n, row in enumerate(rows):
        images.setdefault((row.scene_id, row.im_id), []).append(n)
    out = list(rows)
    for (scene, im), members in images.items():
        rgb, K = bop.read_image(scenes[scene], im), annotations[scene][im]["K"]
        H, W = rgb.shape[:2]
        poses = [(objects.get(rows[n].obj_id), np.asarray(rows[n].R, float), np.asarray(rows[n].t, float))
                 for n in members]
        depths = [render_depth(o.vertices, o.faces, R, t, K, W, H) if t[2] > 0 else np.zeros((H, W), np.float32)
                  for o, R, t in poses] if args.occluders else []
        for k, (n, (obj, R, t)) in enumerate(zip(members, poses)):
            hidden = nearer_pixels(depths, k, float(t[2])) if args.occluders else None
            fit = outline_stage.fit_to_mask(obj, rgb, K, R, t, read, net.size, MAX_SCALE, STEP_DEG, hidden)
            out[n] = replace(rows[n], R=fit.R, t=fit.t)
        print(f"image {scene}/{im}: {len(members)} poses fitted", flush=True)
    write_bop_results(args.out, out)
    print(f"wrote {args.out}: score it with simtest eval --data {args.data} --results {args.out}")


if __name__ == "__main__":
    main()
