"""``simtest tolerance``: per-object maps of grasp success against the oracle's pose error along one axis."""

from __future__ import annotations

import argparse
import sys

from simtest.cli.common import add_backend_options, common_parser, locks_output
from simtest.errors import ConfigError

AXES_HELP = ("t_x, t_y, t_z (translation along the object's axes), t_ray (along the camera's viewing ray), "
             "r_x, r_y, r_z (rotation about the object's axes)")


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "tolerance", parents=[common_parser()],
        help="grasp success vs the oracle's pose error along each axis, per object (tolerance maps)",
        description="Per graspable object, closed-loop grasp episodes with the oracle's pose off by an exact "
                    f"error along one axis at a time ({AXES_HELP}) over a grid of magnitudes. Writes "
                    "tolerance.csv (successes, episodes and 95 %% Wilson interval per object, axis and "
                    "magnitude), tolerance.json (per object and axis the largest error keeping success >= "
                    "90 %%), episodes.csv, tolerance.png and report.html (see docs/grasp_tolerance.md).")
    p.add_argument("--objects", default="builtin-small", help="object set (default builtin-small)")
    p.add_argument("--target", default=None, help="comma-separated obj_ids or names to map (default: every "
                                                  "graspable object of the set)")
    p.add_argument("--units", default="auto", choices=["m", "cm", "mm", "auto"], help="units of mesh files")
    p.add_argument("--scale", type=float, default=1.0, help="factor on top of --units (default 1)")
    p.add_argument("--axes", default=None, help=f"comma-separated axes (default all: {AXES_HELP})")
    p.add_argument("--magnitudes", nargs="+", default=None, metavar="UNIT=LIST",
                   help="the grids, e.g. mm=0,5,10,20,40 deg=0,10,30,60,90 (mm for the t_* axes, deg for the "
                        "r_* axes; each must include 0; default mm=0,5,10,15,20,30,40,60 deg=0,5,10,20,30,45,60,90)")
    p.add_argument("--episodes-per-cell", type=int, default=10, help="episodes per object, axis and magnitude "
                                                                     "(default 10)")
    p.add_argument("--level", type=float, default=0.9, help="success rate a tolerated error keeps (default 0.9)")
    p.add_argument("--width", type=int, default=64, help="wrist camera width, pixels (default 64: the oracle "
                                                         "reads no image)")
    p.add_argument("--height", type=int, default=None, help="wrist camera height (default 3/4 of the width)")
    p.add_argument("--seed", type=int, default=0, help="master seed (default 0)")
    p.add_argument("--workers", type=int, default=1, help="worker processes (each owns whole episodes)")
    add_backend_options(p, "episode")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--overwrite", action="store_true", help="write into a non-empty --out")
    p.set_defaults(func=run)
    locks_output(p)


def parse_magnitudes(items: list[str] | None) -> dict[str, tuple[float, ...]]:
    """``{"mm": (...), "deg": (...)}`` from ``UNIT=LIST`` items (only the units given).

    Raises:
        ConfigError: An item that is not ``mm=...`` or ``deg=...`` with numbers.
    """
    out: dict[str, tuple[float, ...]] = {}
    for item in items or []:
        unit, sep, text = item.partition("=")
        if not sep or unit not in ("mm", "deg"):
            raise ConfigError(f"--magnitudes items must be mm=LIST or deg=LIST (e.g. mm=0,10,20), got {item!r}")
        try:
            out[unit] = tuple(float(v) for v in text.split(",") if v.strip())
        except ValueError:
            raise ConfigError(f"--magnitudes {unit}= must list numbers separated by commas, got {text!r}") from None
    return out


def split_list(text: str | None) -> tuple:
    """The comma-separated items of ``text`` (ints where they are digits); ``()`` for None."""
    if text is None:
        return ()
    return tuple(int(t) if t.strip().isdigit() else t.strip() for t in text.split(",") if t.strip())


def _tolerated_text(entry: dict) -> str:
    """One axis of ``tolerance.json`` as text: ``any`` (continuous symmetry), ``-`` (none), else ``10mm``."""
    if entry["symmetry"] == "continuous":
        return "any"
    if entry["tolerated"] is None:
        return "-"
    return f"{entry['tolerated']:g}{entry['unit']}" + ("+" if entry["first_below"] is None else "")


def run(args: argparse.Namespace) -> int:
    from simtest.envs.oracle_episodes import EpisodeSetup
    from simtest.envs.tolerance import ROT_DEG, TRANS_MM, ToleranceConfig, run_tolerance, write_tolerance
    from simtest.estimators.oracle import ERROR_AXES
    from simtest.io.files import prepare_out_dir
    from simtest.viz.tolerance_page import write_tolerance_report

    prepare_out_dir(args.out, overwrite=args.overwrite)
    grids = parse_magnitudes(args.magnitudes)
    setup = EpisodeSetup(objects=args.objects, units=args.units, scale=args.scale, width=args.width,
                         height=args.height if args.height is not None else args.width * 3 // 4,
                         workers=args.workers, backend=args.backend or "local", ray_address=args.ray_address)
    cfg = ToleranceConfig(setup=setup, targets=split_list(args.target),
                          axes=tuple(str(a) for a in split_list(args.axes)) or ERROR_AXES,
                          trans_mm=grids.get("mm", TRANS_MM), rot_deg=grids.get("deg", ROT_DEG),
                          episodes_per_cell=args.episodes_per_cell, seed=args.seed, level=args.level)
    cfg.check()  # before the objects are loaded
    result = run_tolerance(cfg, progress=not args.quiet)
    command = ["simtest", *sys.argv[1:]]
    result.summary["command_line"] = command
    paths = write_tolerance(result, args.out)
    paths.update(write_tolerance_report(result.summary, result.cells, args.out, command))
    for name, o in result.summary["objects"].items():
        print(f"{name}: " + ", ".join(f"{axis} {_tolerated_text(e)}" for axis, e in o["axes"].items()))
    s = result.summary
    print(f"{s['episodes']} episodes in {s['wall_s']:.1f} s ({s['episodes_per_s']:.2f} episodes/s); wrote "
          f"{args.out}/tolerance.csv, tolerance.json, episodes.csv, tolerance.png, report.html")
    return 0
