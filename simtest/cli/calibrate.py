"""``simtest calibrate``: which pose-error metric predicts grasp success (ROC AUC, thresholds)."""

from __future__ import annotations

import argparse
import math
import sys

from simtest.cli.common import add_backend_options, common_parser, locks_output
from simtest.cli.tolerance import split_list
from simtest.errors import ConfigError


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "calibrate", parents=[common_parser()],
        help="how well each pose metric predicts grasp success (ROC AUC, best threshold, BOP thresholds)",
        description="Closed-loop grasp episodes of the oracle with random errors (a uniformly random direction "
                    "and axis, sizes uniform up to --max-trans-mm and --max-rot-deg), occlusion cycling over "
                    "--occlusions; per metric (ADD(-S), MSSD, MSPD, re, te, BOP's AR) the ROC AUC of its error "
                    "as a predictor of success with a 95 %% bootstrap interval, the best-separating threshold, "
                    "the largest threshold whose correct episodes succeed >= 90 %%, and the success rate at "
                    "BOP's thresholds. With --estimator, the errors real estimators make instead (pooled; "
                    "a miss is a failure with infinite error; VSD added). Writes calibration.csv, "
                    "calibration_thresholds.csv, calibration_episodes.csv, calibration.json, calibration.png "
                    "and calibration.html, with --estimator also calibration_estimators.csv "
                    "(see docs/grasp_tolerance.md).")
    p.add_argument("--estimator", action="append", default=[], metavar="NAME[,NAME...]",
                   help="real estimators pooled (names as simtest grasp --estimator takes: icp, segicp, "
                        "keypoints, ...; comma-separated or repeated); default: the oracle with random errors")
    p.add_argument("--estimator-opt", action="append", default=[], metavar="[NAME:]KEY=VALUE",
                   help="estimator option (repeatable), for every --estimator, or for NAME only")
    p.add_argument("--objects", default="builtin-small", help="object set (default builtin-small)")
    p.add_argument("--target", default=None, help="comma-separated obj_ids or names (default: every graspable "
                                                  "object of the set)")
    p.add_argument("--units", default="auto", choices=["m", "cm", "mm", "auto"], help="units of mesh files")
    p.add_argument("--scale", type=float, default=1.0, help="factor on top of --units (default 1)")
    p.add_argument("--episodes", type=int, default=50, help="episodes per object (default 50)")
    p.add_argument("--max-trans-mm", type=float, default=None,
                   help="the oracle's largest translation error, mm (default 40; not with --estimator)")
    p.add_argument("--max-rot-deg", type=float, default=None,
                   help="the oracle's largest rotation error, degrees (default 60; not with --estimator)")
    p.add_argument("--occlusions", default="L0,L1,L2", help="occlusion levels cycled (default L0,L1,L2)")
    p.add_argument("--resamples", type=int, default=1000, help="bootstrap resamples (default 1000)")
    p.add_argument("--width", type=int, default=None,
                   help="wrist camera width, pixels (default 64 for the oracle, 320 with --estimator)")
    p.add_argument("--height", type=int, default=None, help="wrist camera height (default 3/4 of the width)")
    p.add_argument("--seed", type=int, default=0, help="master seed (default 0)")
    p.add_argument("--workers", type=int, default=1, help="worker processes (each owns whole episodes)")
    add_backend_options(p, "episode")
    p.add_argument("--out", required=True, help="output folder")
    p.add_argument("--overwrite", action="store_true", help="write into a non-empty --out")
    p.set_defaults(func=run)
    locks_output(p)


def _num(v, digits: int = 3) -> str:
    return "-" if v is None or (isinstance(v, float) and math.isnan(v)) else f"{v:.{digits}g}"


def estimator_options(names: tuple[str, ...], items: list[str]) -> dict[str, dict]:
    """``--estimator-opt`` items (``KEY=VALUE`` for every estimator, ``NAME:KEY=VALUE`` for one) as options per
    name, checked against each estimator's signature.

    Raises:
        ConfigError: Options without estimators, a NAME not among ``names``, or an option an estimator does
            not take (its valid ones listed).
    """
    from simtest.errors import ConfigError
    from simtest.estimators.options import parse_options
    from simtest.estimators.registry import check_estimator_options

    if items and not names:
        raise ConfigError(f"--estimator-opt needs --estimator (the oracle's random errors are set by "
                          f"--max-trans-mm and --max-rot-deg); got {items!r}")
    out: dict[str, dict] = {n: {} for n in names}
    for item in items:
        head, eq, _ = item.partition("=")
        name, colon, _ = head.partition(":")
        if colon and eq:
            if name not in out:
                raise ConfigError(f"--estimator-opt {item!r} names {name!r}, not one of the estimators "
                                  f"{list(names)!r}")
            out[name].update(parse_options([item[len(name) + 1:]]))
        else:
            for n in names:
                out[n].update(parse_options([item]))
    for n in names:
        check_estimator_options(n, out[n])
    return {n: o for n, o in out.items() if o}


def run(args: argparse.Namespace) -> int:
    from simtest.envs.calibration import CalibrationConfig, run_calibration, write_calibration
    from simtest.envs.oracle_episodes import EpisodeSetup
    from simtest.io.files import prepare_out_dir
    from simtest.viz.tolerance_page import write_calibration_report

    names = tuple(dict.fromkeys(str(n) for item in args.estimator for n in split_list(item)))
    names = () if names == ("oracle",) else names  # the oracle with random errors, the default
    options = estimator_options(names, args.estimator_opt)
    if names and (args.max_trans_mm is not None or args.max_rot_deg is not None):
        raise ConfigError(f"--max-trans-mm and --max-rot-deg set the oracle's random errors; with --estimator "
                          f"{','.join(names)} the errors are the estimators' own: drop them")
    args.max_trans_mm = 40.0 if args.max_trans_mm is None else args.max_trans_mm
    args.max_rot_deg = 60.0 if args.max_rot_deg is None else args.max_rot_deg
    prepare_out_dir(args.out, overwrite=args.overwrite)
    width = args.width if args.width is not None else (320 if names else 64)
    setup = EpisodeSetup(objects=args.objects, units=args.units, scale=args.scale, width=width,
                         height=args.height if args.height is not None else width * 3 // 4,
                         workers=args.workers, backend=args.backend or "local", ray_address=args.ray_address,
                         mspd=True)
    cfg = CalibrationConfig(setup=setup, targets=split_list(args.target), episodes_per_object=args.episodes,
                            max_trans_mm=args.max_trans_mm, max_rot_deg=args.max_rot_deg,
                            occlusions=tuple(str(o) for o in split_list(args.occlusions)), seed=args.seed,
                            resamples=args.resamples, estimators=names, estimator_options=options)
    cfg.check()
    result = run_calibration(cfg, progress=not args.quiet)
    command = ["simtest", *sys.argv[1:]]
    result.summary["command_line"] = command
    write_calibration(result, args.out)
    write_calibration_report(result.summary, result.metrics, result.thresholds, args.out, command)
    print("| metric | AUC | 95 % interval | best threshold | threshold for 90 % success |")
    print("|---|---:|---|---:|---:|")
    for r in result.metrics:
        unit = f" {r['unit']}" if r["unit"] else ""
        print(f"| {r['label']} | {_num(r['auc'])} | {_num(r['auc_lo'])} - {_num(r['auc_hi'])} | "
              f"{_num(r['best_threshold'])}{unit} | {_num(r['threshold_90'])}{unit} |")
    s = result.summary
    for name, e in s.get("estimators", {}).items():
        print(f"{name}: {e['successes']}/{e['episodes']} succeeded (95 % CI {100 * e['ci95_lo']:.0f}-"
              f"{100 * e['ci95_hi']:.0f} %), {e['misses']} without an estimate")
    print(f"{s['successes']}/{s['episodes']} episodes succeeded; {s['wall_s']:.1f} s "
          f"({s['episodes_per_s']:.2f} episodes/s); wrote {args.out}/calibration.csv, calibration.html")
    return 0
