"""``simtest corrupt``: preview the image corruptions, or write a corrupted copy of a BOP dataset."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from simtest.cli.common import (LazyChoices, add_backend_options, add_no_progress_alias, backend_from_args,
                                common_parser, locks_output)
from simtest.errors import ConfigError, DatasetError


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "corrupt", parents=[common_parser()],
        help="preview image corruptions, or write a corrupted copy of a BOP dataset",
        description="Preview: a grid of corruptions x severities 1..5 of one image. Dataset: a copy of a BOP "
                    "dataset with corrupted RGB (ImageNet-C), pasted occluders (cutouts of the dataset's objects by "
                    "default, or noise shapes) and/or depth-sensor noise; ground truth is copied unchanged (a paste occlusion updates mask_visib and "
                    "scene_gt_info.json), parameters and seed go to corruption.json.",
    )
    mode = p.add_mutually_exclusive_group(required=True)
    mode.add_argument("--preview", metavar="IMAGE", help="image to preview the corruptions on")
    mode.add_argument("--in", dest="in_dir", metavar="DATASET", help="BOP dataset to corrupt")
    mode.add_argument("--list", action="store_true", help="list corruptions, depth presets and occlusion levels")
    p.add_argument("--out", metavar="PATH", help="grid PNG (--preview) or output dataset folder (--in)")
    p.add_argument("--corruptions", default="all", metavar="all|NAME,NAME",
                   help="corruptions shown by --preview (default: all)")
    p.add_argument("--weather", metavar="NAME", help="image corruption (any of the 19 ImageNet-C names)")
    p.add_argument("--severity", type=int, default=4, metavar="S", help="severity 1..5 (default: 4)")
    p.add_argument("--occlusion", metavar="L1|L2|L3", help="2D occlusion level (occluders pasted on the image)")
    p.add_argument("--occlusion-kind", default=None, choices=["objects", "paste"],
                   help="objects (default: cutouts of the dataset's own unoccluded rendered objects, with their "
                        "visible masks; without the option, a dataset with no usable instance, e.g. no masks, "
                        "falls back to paste with a warning, recorded in corruption.json; given explicitly, that "
                        "is an error) or paste (noise/crop-textured ellipses and polygons)")
    p.add_argument("--occlusion-definition", default="pascal3d+", metavar="DEF",
                   help="level bands: pascal3d+ (default) or objectcentric")
    p.add_argument("--depth-noise", choices=LazyChoices("simtest.corrupt", "DEPTH_PRESETS"),
                   help="depth-sensor noise preset")
    p.add_argument("--seed", type=int, default=0, help="seed (default: 0)")
    p.add_argument("--overwrite", action="store_true", help="replace a non-empty output dataset folder")
    p.add_argument("--workers", type=int, default=1, metavar="N",
                   help="with --in: worker processes (or Ray CPUs), each corrupting whole scenes (default 1: "
                        "this process); the output is the same for any N")
    add_backend_options(p, "scene")
    add_no_progress_alias(p)
    p.set_defaults(func=run)
    locks_output(p, lambda args: args.out if args.in_dir else None)


def _write_png(path: Path, rgb) -> None:
    import cv2

    from simtest.io.files import atomic_write_bytes

    ok, buf = cv2.imencode(".png", cv2.cvtColor(rgb, cv2.COLOR_RGB2BGR))
    if not ok:
        raise ConfigError(f"could not encode the preview grid for {path}")
    atomic_write_bytes(path, buf.tobytes())


def run(args: argparse.Namespace) -> int:
    from simtest.backend import RunStats
    from simtest.corrupt import (CORRUPTIONS, DEPTH_PRESETS, OCCLUSION_BANDS, CorruptionSpec, corrupt_dataset,
                                 preview_grid)

    if args.list:
        print("image corruptions (severity 1..5):", ", ".join(CORRUPTIONS))
        print("depth-noise presets:")
        for name, preset in DEPTH_PRESETS.items():
            print(f"  {name}: {preset.description}")
        for definition, levels in OCCLUSION_BANDS.items():
            bands = "; ".join(f"L{lvl} FG {fg[0]:.0%}-{fg[1]:.0%} BG {bg[0]:.0%}-{bg[1]:.0%}"
                              for lvl, (fg, bg, _t) in levels.items())
            print(f"occlusion levels ({definition}): {bands}")
        return 0
    if not args.out:
        raise ConfigError("--out is required with --preview and --in")

    if args.preview:
        import cv2

        if Path(args.out).is_dir():
            raise ConfigError(f"--out {args.out!r} is a folder; with --preview give the PNG file to write")
        src = Path(args.preview)
        bgr = cv2.imread(str(src), cv2.IMREAD_COLOR)
        if bgr is None:
            raise ConfigError(f"cannot read preview image {src}")
        names = None if args.corruptions.strip() == "all" else [n.strip() for n in args.corruptions.split(",") if n.strip()]
        grid = preview_grid(cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB), names, seed=args.seed)
        _write_png(Path(args.out), grid)
        print(f"wrote {args.out} ({grid.shape[1]}x{grid.shape[0]} px)")
        return 0

    spec = CorruptionSpec(weather=args.weather, severity=args.severity, depth_noise=args.depth_noise,
                          occlusion=args.occlusion, occlusion_kind=args.occlusion_kind or "objects",
                          occlusion_definition=args.occlusion_definition)
    if spec.is_identity:
        raise ConfigError("nothing to corrupt: give at least one of --weather, --occlusion, --depth-noise")
    if not Path(args.in_dir).is_dir():
        raise DatasetError(f"dataset folder {args.in_dir} does not exist")
    backend, stats = backend_from_args(args), RunStats()
    record = corrupt_dataset(args.in_dir, args.out, spec, seed=args.seed, overwrite=args.overwrite,
                             progress=not args.quiet, backend=backend, stats=stats,
                             cutout_fallback=args.occlusion_kind is None)
    if not args.quiet:
        print(f"simtest corrupt: {stats.summary()}", file=sys.stderr)
    line = f"wrote {args.out}: {record['images']} images, {spec.label()}, seed {args.seed}"
    occ = record.get("occlusion", {})
    if "mean_fg_fraction" in occ:
        line += (f"; occlusion FG {occ['mean_fg_fraction']:.0%} BG {occ['mean_bg_fraction']:.0%} "
                 f"(in band {occ['in_band_fraction']:.0%}, {occ['definition']})")
    if "cutout_fallback" in occ:
        line += "; the dataset has no object cutouts: noise shapes pasted (see corruption.json)"
    print(line)
    return 0
