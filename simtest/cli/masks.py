"""``simtest masks --data DATASET``: render the ground-truth masks of a BOP dataset that ships none
(:func:`simtest.io.bop_masks.write_gt_masks`)."""

from __future__ import annotations

import argparse

from simtest.cli.common import common_parser


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "masks", parents=[common_parser()],
        help="render mask/ and mask_visib/ of a BOP dataset from its poses and models (for sets shipped without)",
        description="Render every annotated instance's amodal mask (mask/) and visible mask (mask_visib/) from "
                    "the ground-truth poses and DATASET/models, as the BOP toolkit's calc_gt_masks does. "
                    "Visibility: with depth/ the BOP19 rule (model distance <= measured distance + 15 mm, or "
                    "no reading); without depth the nearest of the annotated objects (occlusion by "
                    "unannotated clutter is not seen). scene_gt_info.json is kept as distributed. With --out "
                    "the masks go to a new dataset folder whose other files link to DATASET (a read-only "
                    "download stays untouched); without, into DATASET's scene folders.",
    )
    p.add_argument("--data", required=True, metavar="DATASET", help="BOP dataset root (with models/)")
    p.add_argument("--out", metavar="DIR", help="new dataset folder (default: write into DATASET)")
    p.add_argument("--split", default=None, help="split folder (default: the dataset's only split)")
    p.add_argument("--overwrite", action="store_true", help="replace existing mask folders")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import numpy as np

    from simtest.io.bop_masks import write_gt_masks
    from simtest.objects.loaders import load_dataset_objects

    objects = load_dataset_objects(args.data)
    meshes = {int(o.obj_id): (np.asarray(o.vertices, np.float64), np.asarray(o.faces)) for o in objects}
    report = write_gt_masks(args.data, meshes, out_dir=args.out, split=args.split,
                            overwrite=bool(args.overwrite), progress=not args.quiet)
    print(report.summary())
    return 0
