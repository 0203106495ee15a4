"""``simtest objects``: list an object set, export it as BOP models, render a preview of one object, fill its
caches ahead of a run."""

from __future__ import annotations

import argparse
import time
from pathlib import Path

from simtest.cli.common import add_backend_options, backend_from_args, common_parser, locks_output
from simtest.errors import AssetError

__all__ = ["register", "object_table", "category_table", "entry_table"]

#: A set with more objects than this (in several categories) is listed with its category table first.
SUMMARY_MIN_OBJECTS = 30


def register(subparsers) -> None:
    parser = subparsers.add_parser("objects", help="list, export or preview object sets",
                                   description="List, export or preview object sets.")
    sub = parser.add_subparsers(dest="objects_command", metavar="SUBCOMMAND")

    def common(p: argparse.ArgumentParser) -> None:
        p.add_argument("--set", dest="set", default="builtin",
                       help="builtin, builtin-small, a BOP models folder, a mesh folder or a mesh file")
        p.add_argument("--units", default="auto", choices=["m", "cm", "mm", "auto"],
                       help="units of mesh files (auto: metres, refusing a diameter outside 1 cm .. 1.5 m)")
        p.add_argument("--scale", type=float, default=1.0,
                       help="factor on top of --units (metres = file units x units x scale; default 1)")
        p.add_argument("--seed", type=int, default=0, help="seed of the built-in sets")
        p.add_argument("--symmetry", default="auto", choices=["auto", "geometry", "none"],
                       help="symmetries of mesh files that declare none: detect and use them (auto: by shape, and "
                            "by colours for textured or coloured meshes; geometry: by shape alone) or not (none)")

    p_list = sub.add_parser("list", parents=[common_parser()], help="print a table of the objects")
    common(p_list)
    p_list.add_argument("--no-grasps", action="store_true",
                        help="skip grasp sampling and the collision parts it needs (faster on a set's first use)")
    p_list.add_argument("--by-category", action="store_true",
                        help="print only the category table (objects and ids per category; reads no mesh)")
    p_list.add_argument("--category", metavar="NAME[,NAME]",
                        help="list only the objects of these categories (with sizes, mass, symmetry, grasps)")
    p_list.set_defaults(func=_cmd_list)

    p_exp = sub.add_parser("export", parents=[common_parser()], help="write the set as a BOP models/ folder (millimetres)")
    common(p_exp)
    p_exp.add_argument("--out", required=True, help="output folder (the models/ folder itself)")
    p_exp.add_argument("--overwrite", action="store_true", help="allow writing into a non-empty folder")
    p_exp.set_defaults(func=_cmd_export)
    locks_output(p_exp)

    p_prev = sub.add_parser("preview", parents=[common_parser()],
                            help="render objects from a few views into a PNG (one row per object)")
    common(p_prev)
    p_prev.add_argument("obj_id", help="object id, comma-separated ids, or 'all'")
    p_prev.add_argument("--out", required=True, help="PNG file to write")
    p_prev.add_argument("--size", type=int, default=256, help="pixels per view (square)")
    p_prev.add_argument("--views", type=int, default=4, help="views per object, at evenly spaced azimuths")
    p_prev.set_defaults(func=_cmd_preview)

    p_prep = sub.add_parser(
        "prepare", parents=[common_parser()],
        help="compute and cache every object's collision parts (and a lazily read mesh's symmetries) ahead of a run",
        description="Compute what each object of the set needs on first use (the convex decomposition of concave "
                    "objects, detected symmetries of lazily read meshes) and cache it under $SIMTEST_CACHE "
                    "(default ~/.cache/simtest), so the first scenes of a run do not wait for it. On a cluster, "
                    "run it once with a shared $SIMTEST_CACHE (or on every node with a cache per node).")
    common(p_prep)
    locks_output(p_prep, lambda args: _cache_folder())
    p_prep.add_argument("--workers", type=int, default=1, metavar="N", help="objects prepared at once (processes)")
    add_backend_options(p_prep, "object")
    p_prep.set_defaults(func=_cmd_prepare)

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
    return _text_table(header, rows)


def _load(args):
    from simtest.objects import load_object_set

    return load_object_set(args.set, units=args.units, seed=args.seed, scale=args.scale, symmetry=args.symmetry)


def _id_ranges(ids: list[int]) -> str:
    """``"1-5, 9, 12-13"`` for sorted ids."""
    out: list[str] = []
    start = prev = None
    for i in ids + [None]:
        if start is not None and (i is None or i != prev + 1):
            out.append(str(start) if start == prev else f"{start}-{prev}")
            start = None
        if i is not None and start is None:
            start = i
        prev = i
    return ", ".join(out)


def _text_table(header: list[str], rows: list[list[str]]) -> str:
    """Left-aligned columns two spaces apart, one line per row after the header."""
    widths = [max(len(r[i]) for r in [header] + rows) for i in range(len(header))]
    return "\n".join("  ".join(c.ljust(w) for c, w in zip(r, widths)).rstrip() for r in [header] + rows)


def category_table(objects) -> str:
    """A fixed-width text table with one row per category: its number of objects and their ids (from the
    set's entries: no mesh is read)."""
    by_cat: dict[str, list[int]] = {}
    for e in objects.entries:
        by_cat.setdefault(e.category, []).append(e.obj_id)
    rows = [[c, str(len(ids)), _id_ranges(sorted(ids))] for c, ids in sorted(by_cat.items())]
    return _text_table(["category", "objects", "obj_ids"], rows)


def entry_table(entries, root: str | None = None) -> str:
    """A fixed-width text table of object entries: id, name, category, file (relative to ``root`` when it lies
    in it; no mesh is read)."""
    def where(source: str) -> str:
        if root and Path(source).is_relative_to(root):
            return str(Path(source).relative_to(root))
        return source

    return _text_table(["id", "name", "category", "file"],
                       [[str(e.obj_id), e.name, e.category, where(e.source)] for e in entries])


def _chosen_categories(objects, text: str | None) -> list[str] | None:
    """The categories named by ``--category`` (unknown names list the known ones), or ``None``."""
    if text is None:
        return None
    names = [t.strip() for t in text.split(",") if t.strip()]
    unknown = [n for n in names if n not in objects.categories]
    if unknown or not names:
        raise AssetError(f"--category {text!r}: unknown category {', '.join(unknown) or '(none given)'}; "
                         f"known: {', '.join(objects.categories)}")
    return names


def _cmd_list(args) -> int:
    from simtest.objects.prepare import prepare_set

    objects = _load(args)
    cats = objects.categories
    chosen = _chosen_categories(objects, args.category)
    listed = ": " + ", ".join(cats) if len(cats) <= 8 else ""
    print(f"# {objects.name}: {len(objects)} objects in {len(cats)} categories{listed}")
    if len(cats) > 1 and (args.by_category or (chosen is None and len(objects) > SUMMARY_MIN_OBJECTS)):
        print(category_table(objects))
        if args.by_category:
            return 0
        print()
    ids = [e.obj_id for e in objects.entries if chosen is None or e.category in chosen]
    if objects.lazy and chosen is None:
        print("# meshes are read on first use; --category NAME lists sizes, mass, symmetry and grasps")
        print(entry_table(objects.entries, objects.name))
        return 0
    # First use of a set: collision parts (CoACD, cached on disk) and grasps per object, under a progress bar
    # naming the object being worked on (shown when slow); the table is then made from what is in memory.
    prepare_set(objects, ids, collision=not args.no_grasps, grasps=not args.no_grasps, progress=not args.quiet)
    print(object_table([objects.get(i) for i in ids], grasps=not args.no_grasps))
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
    import numpy as np

    if not 1 <= args.views <= 16 or not 16 <= args.size <= 2048:
        raise AssetError(f"--views must be 1..16 and --size 16..2048 pixels, got {args.views} and {args.size}")
    objects = _load(args)
    chosen = _preview_objects(objects, args.obj_id)
    image = np.concatenate([render_preview(o, size=args.size, views=args.views) for o in chosen], axis=0)
    out.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(image).save(out)
    print(f"wrote {out} ({', '.join(o.name for o in chosen)}, {image.shape[1]}x{image.shape[0]} px)")
    return 0


def _cmd_prepare(args) -> int:
    import sys

    from simtest.backend import RunStats
    from simtest.objects.cache import cache_dir
    from simtest.objects.prepare import prepare_objects

    backend, stats = backend_from_args(args), RunStats()
    start = time.perf_counter()
    done = prepare_objects(args.set, units=args.units, seed=args.seed, scale=args.scale, symmetry=args.symmetry,
                           backend=backend, progress=not args.quiet, stats=stats)
    seconds = time.perf_counter() - start
    if not args.quiet:
        print(f"simtest objects prepare: {stats.summary()}", file=sys.stderr)
    print(_text_table(["id", "name", "collision", "parts", "seconds"],
                      [[str(r.obj_id), r.name, r.collision, str(r.parts), f"{r.seconds:.2f}"] for r in done]))
    count = {k: sum(r.collision == k for r in done) for k in ("computed", "cached", "hull")}
    print(f"# {len(done)} objects in {seconds:.1f} s: {count['computed']} decompositions computed, "
          f"{count['cached']} already cached, {count['hull']} convex (hull); cache: {cache_dir()}")
    return 0


def _preview_objects(objects, text: str) -> list:
    """The objects named by ``text``: ``all``, an id, or comma-separated ids (unknown ids list the known)."""
    if text.strip() == "all":
        return list(objects)
    try:
        ids = [int(t) for t in text.split(",") if t.strip()]
    except ValueError:
        raise AssetError(f"obj_id must be an id, comma-separated ids or 'all', got {text!r}") from None
    if not ids:
        raise AssetError(f"obj_id must be an id, comma-separated ids or 'all', got {text!r}")
    return [objects.get(i) for i in ids]


def _cache_folder():
    """The object cache folder that ``objects prepare`` fills (one preparer at a time)."""
    from simtest.objects.cache import cache_root

    return cache_root()
