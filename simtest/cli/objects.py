"""``simtest objects``: list an object set, export it as BOP models, render a preview of one object."""

from __future__ import annotations

import argparse
from pathlib import Path

from simtest.cli.common import common_parser
from simtest.errors import AssetError

__all__ = ["register", "object_table"]


def register(subparsers) -> None:
    parser = subparsers.add_parser("objects", help="list, export or preview object sets",
                                   description="List, export or preview object sets.")
    sub = parser.add_subparsers(dest="objects_command", metavar="SUBCOMMAND")

    def common(p: argparse.ArgumentParser) -> None:
        p.add_argument("--set", dest="set", default="builtin",
                       help="builtin, builtin-small, a BOP models folder, a mesh folder or a mesh file")
        p.add_argument("--units", default="auto", choices=["m", "mm", "auto"], help="units of mesh files")
        p.add_argument("--seed", type=int, default=0, help="seed of the built-in sets")
        p.add_argument("--symmetry", default="auto", choices=["auto", "none"],
                       help="symmetries of mesh files that declare none: detect and use them (auto) or not (none)")

    p_list = sub.add_parser("list", parents=[common_parser()], help="print a table of the objects")
    common(p_list)
    p_list.add_argument("--no-grasps", action="store_true", help="skip grasp sampling (faster)")
    p_list.set_defaults(func=_cmd_list)

    p_exp = sub.add_parser("export", parents=[common_parser()], help="write the set as a BOP models/ folder (millimetres)")
    common(p_exp)
    p_exp.add_argument("--out", required=True, help="output folder (the models/ folder itself)")
    p_exp.add_argument("--overwrite", action="store_true", help="allow writing into a non-empty folder")
    p_exp.set_defaults(func=_cmd_export)

    p_prev = sub.add_parser("preview", parents=[common_parser()], help="render one object from a few views into a PNG")
    common(p_prev)
    p_prev.add_argument("obj_id", type=int, help="object id")
    p_prev.add_argument("--out", required=True, help="PNG file to write")
    p_prev.add_argument("--size", type=int, default=256, help="pixels per view (square)")
    p_prev.set_defaults(func=_cmd_preview)

    parser.set_defaults(func=lambda args: (parser.print_help(), 2)[1])


def object_table(objects, grasps: bool = True) -> str:
    """A fixed-width text table: id, name, category, diameter/size (mm), mass (g), symmetry, grasps.

    The symmetry column says where a symmetry comes from: ``continuous(z)`` (declared), ``continuous(z)
    detected`` (detected and used) or ``... detected, not used`` (``--symmetry none``).
    """
    from simtest.objects.symmetry_detect import symmetry_status

    header = ["id", "name", "category", "diam_mm", "size_mm", "mass_g", "symmetry", "graspable", "grasps"]
    rows = []
    for o in objects:
        n = len(o.grasps) if grasps else None
        rows.append([str(o.obj_id), o.name, o.category, f"{o.diameter * 1000:.1f}",
                     "x".join(f"{s * 1000:.0f}" for s in o.size), f"{o.mass * 1000:.0f}", symmetry_status(o),
                     "-" if n is None else ("yes" if (o.graspable if o.graspable_override is not None else n > 0)
                                            else "no"),
                     "-" if n is None else str(n)])
    widths = [max(len(r[i]) for r in [header] + rows) for i in range(len(header))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in [header] + rows]
    return "\n".join(lines)


def _load(args):
    from simtest.objects import load_object_set

    return load_object_set(args.set, units=args.units, seed=args.seed, symmetry=args.symmetry)


def _cmd_list(args) -> int:
    objects = _load(args)
    print(f"# {objects.name}: {len(objects)} objects, categories: {', '.join(objects.categories)}")
    print(object_table(objects, grasps=not args.no_grasps))
    return 0


def _cmd_export(args) -> int:
    from simtest.io.bop_models import write_bop_models
    from simtest.io.files import prepare_out_dir

    out = Path(args.out)
    prepare_out_dir(out, overwrite=args.overwrite)
    objects = _load(args)
    write_bop_models(objects, out)
    print(f"wrote {len(objects)} models to {out}")
    return 0


def _cmd_preview(args) -> int:
    from PIL import Image

    from simtest.objects.preview import render_preview

    out = Path(args.out)
    if out.suffix.lower() != ".png":
        raise AssetError(f"--out must be a .png file, got {out}")
    objects = _load(args)
    obj = objects.get(args.obj_id)
    image = render_preview(obj, size=args.size)
    out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(image).save(out)
    print(f"wrote {out} ({obj.name}, {image.shape[1]}x{image.shape[0]} px)")
    return 0
