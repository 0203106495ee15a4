"""``simtest show PATH``: draw a dataset's ground truth, an evaluation run's estimates or a grasp run's
episodes into PNG files (:func:`simtest.viz.show.show`)."""

from __future__ import annotations

import argparse
from pathlib import Path

from simtest.cli.common import common_parser
from simtest.errors import ConfigError


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "show", parents=[common_parser()],
        help="draw a dataset's ground truth, an evaluation's estimates or a grasp run's episodes as PNG",
        description="Draw PATH into PNG pictures. A BOP dataset: per image the RGB with each instance's visible "
                    "(solid) and amodal (dashed) mask contour, 3D box and axes from the ground-truth pose, name "
                    "and visib_fract; the depth colourized (holes black); dense channels (instances, coords, "
                    "normals, flow) and scene_captions.json when present. An evaluation folder (simtest eval "
                    "--out): the ground truth (green) and the estimate (magenta) with each target's errors and "
                    "whether it counted as correct (ADD(-S) < 0.1d); --worst N, --failures. A grasp run "
                    "(simtest grasp --out): one card per episode with outcome and pose error (first and last "
                    "frame of its clip with --video). --out FILE.png writes one contact sheet, --out DIR one "
                    "PNG per card.",
    )
    p.add_argument("path", metavar="PATH", help="dataset folder, evaluation folder or grasp run folder")
    p.add_argument("--out", metavar="FILE.png|DIR",
                   help="PNG contact sheet, or a folder for one PNG per card (default: ./show_<name>.png)")
    p.add_argument("--split", default=None, help="split folder of a dataset (default: the dataset's only split)")
    p.add_argument("--scene", type=int, metavar="N", help="only this scene id (default: every scene)")
    sel = p.add_mutually_exclusive_group()
    sel.add_argument("--image", type=int, metavar="K", help="only image id K (of --scene, else of the first "
                                                            "scene that has it)")
    sel.add_argument("--images", type=int, default=4, metavar="N",
                     help="the first N images of the selection (default 4)")
    p.add_argument("--worst", type=int, metavar="N", help="evaluation: the N worst targets (by --by)")
    p.add_argument("--by", default="mssd", metavar="COLUMN",
                   help="errors.csv column --worst ranks by: mssd (default), mspd, add_s_or_add, add, adi, re, "
                        "re_sym, te, vsd; misses count as worst")
    p.add_argument("--failures", action="store_true",
                   help="evaluation: the images of failures.csv with their messages")
    p.add_argument("--data", metavar="DATASET",
                   help="evaluation: the dataset evaluated (default: the one metrics.json names)")
    p.add_argument("--scale", type=int, metavar="S",
                   help="integer upscale of the images (default: small images to at least 480 rows)")
    p.add_argument("--episodes", type=int, default=12, metavar="N",
                   help="grasp run: at most N episodes (default 12)")
    p.add_argument("--palette", action="store_true",
                   help="write 256-colour PNGs (a third of the size or less; for documents and reports)")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    from simtest.viz.dataset_page import ImageSelection
    from simtest.viz.show import ShowOptions, show

    if args.scale is not None and not 1 <= args.scale <= 16:
        raise ConfigError(f"--scale must be 1..16, got {args.scale}")
    if args.episodes < 1:
        raise ConfigError(f"--episodes must be >= 1, got {args.episodes}")
    out = Path(args.out) if args.out else Path(f"show_{Path(args.path).resolve().name or 'out'}.png")
    selection = ImageSelection(split=args.split, scene=args.scene, image=args.image, count=args.images)
    opts = ShowOptions(selection=selection, worst=args.worst, by=args.by, failures=args.failures, data=args.data,
                       scale=args.scale, episodes=args.episodes, palette=args.palette)
    result = show(args.path, out, opts)
    what = {"dataset": "image", "eval": "card", "grasp": "episode"}[result.kind]
    where = result.paths[0] if len(result.paths) == 1 else f"{len(result.paths)} files in {out}"
    print(f"wrote {where} ({result.kind}: {result.cards} {what}{'s' if result.cards != 1 else ''}, "
          f"{result.ms_per_card:.0f} ms per {what})")
    return 0
