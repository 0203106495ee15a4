"""``simtest eval``: run a pose estimator over a BOP dataset, or score an existing BOP results CSV."""

from __future__ import annotations

import argparse
import sys

from simtest.cli.common import (add_backend_options, add_fault_options, add_no_progress_alias, backend_from_args,
                                common_parser, locks_output)
from simtest.errors import ConfigError, EstimatorError


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "eval", parents=[common_parser()],
        help="run a pose estimator on a BOP dataset (or score a BOP results CSV) and print the metrics",
        description="Run an estimator (built-in name: oracle, icp, umeyama, keypoints, segicp, track-icp; or "
                    "module:attr) over a BOP dataset, or score a results CSV written by any estimator (--results). Writes results.csv (BOP "
                    "format), metrics.json, errors.csv, failures.csv and metrics.md to --out (a new or empty "
                    "folder, or any folder with --overwrite; never the dataset folder or one inside it).",
    )
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--estimator", metavar="NAME|module:attr|file.py:attr",
                     help="estimator to run: a built-in or installed name, module:attr, or path/to/file.py:attr "
                          "(see docs/plugins.md)")
    src.add_argument("--results", metavar="FILE", help="BOP results CSV to score instead of running an estimator")
    p.add_argument("--data", required=True, metavar="DATASET", help="BOP dataset folder")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder (outside --data)")
    p.add_argument("--overwrite", action="store_true", help="write into a non-empty --out, replacing its results")
    p.add_argument("--opt", action="append", default=[], metavar="KEY=VALUE",
                   help="estimator option (repeatable); values parse as int, float, bool (true/false), none, "
                        "a [list] or 'quoted string', else string; e.g. --opt rot_noise_deg=5")
    p.add_argument("--targets", default=None, choices=("gt-masks", "none"),
                   help="give the estimator the target object ids, plus their ground-truth visible masks if it "
                        "declares needs_gt_masks (runs labelled 'NAME (GT masks)') (default), or nothing; "
                        "localization only")
    p.add_argument("--task", default="localization", choices=("localization", "detection"),
                   help="localization (BOP19, default): the estimator is told which objects each image holds and "
                        "how many; detection (BOP24): it is told nothing, returns any number of scored estimates "
                        "(100 kept per image) and is scored by AP_MSSD, AP_MSPD and their mean, plus top-1 "
                        "classification per category")
    p.add_argument("--split", default=None, help="split folder (default: the dataset's only split)")
    p.add_argument("--labels", metavar="DIR",
                   help="withheld labels of an unlabelled split (DIR/SPLIT/SCENE/scene_gt.json); default "
                        "DATASET/withheld when the dataset was generated with --unlabelled")
    p.add_argument("--scenes", metavar="ID,ID", help="scene ids to evaluate (default: all)")
    p.add_argument("--max-images", type=int, metavar="N", help="evaluate only the first N images")
    p.add_argument("--no-vsd", action="store_true", help="skip VSD (faster; AR is then mean of MSSD and MSPD)")
    p.add_argument("--grasp-tolerance", metavar="TOLERANCE_CSV", default=None,
                   help="a tolerance.csv of simtest tolerance: also score grasp_tolerance, the targets whose "
                        "estimate lies within the object's measured grasp tolerance on every axis "
                        "(docs/grasp_tolerance.md)")
    p.add_argument("--metrics", metavar="NAME,NAME", default=None,
                   help="the metrics the terminal tables show, by registered name (e.g. add_s_or_add_01d,ar,"
                        "grasp_tolerance; default: the standard set); every metric is still computed and written")
    p.add_argument("--tracking", action="store_true",
                   help="also score as tracking (tracking.md, tracking.csv, tracking.png); the default for a "
                        "dataset generated with --rig sequence")
    add_fault_options(p, "image", "an image over it is recorded in failures.csv as 'timeout' and the run goes on",
                      "failures go to failures.csv; exit code 1 if every image failed", declared=True)
    p.add_argument("--workers", type=int, default=1, metavar="N",
                   help="worker processes (or Ray CPUs); each loads the estimator once and runs whole scenes "
                        "(default 1: this process); the files are the same for any N but for the measured times")
    add_backend_options(p, "scene")
    add_no_progress_alias(p)
    p.set_defaults(func=run)
    locks_output(p)


def _shown_metrics(names: str | None, tolerance_csv: str | None) -> list[str]:
    """``--metrics`` as registered metric keys (checked before anything runs).

    Raises:
        ConfigError: An unknown name (the registered ones listed), or ``grasp_tolerance`` without a map.
    """
    from simtest.metrics.registry import metric_keys

    if names is None:
        return []
    keys = [n.strip() for n in names.split(",") if n.strip()]
    known = metric_keys()
    bad = [k for k in keys if k not in known]
    if bad or not keys:
        raise ConfigError(f"--metrics: unknown metric(s) {', '.join(map(repr, bad)) or repr(names)}; registered: "
                          f"{', '.join(known)}")
    if "grasp_tolerance" in keys and not tolerance_csv:
        raise ConfigError("--metrics grasp_tolerance needs the tolerance map it scores against: --grasp-tolerance "
                          "TOLERANCE_CSV (made by simtest tolerance, docs/grasp_tolerance.md)")
    return keys


def run(args: argparse.Namespace) -> int:
    from simtest.backend import RunStats
    from simtest.estimators.options import parse_options
    from simtest.estimators.guard import AUTO_TIMEOUT
    from simtest.evaluation.run import evaluate, format_table, overall_table, score_results

    scenes = None
    if args.scenes:
        try:
            scenes = [int(s) for s in args.scenes.split(",") if s.strip()]
        except ValueError:
            raise ConfigError(f"--scenes must be comma-separated integers, got {args.scenes!r}") from None
    shown = _shown_metrics(args.metrics, args.grasp_tolerance)
    if args.task == "detection" and args.targets is not None:
        raise ConfigError("--targets applies to --task localization; the detection task tells the estimator nothing")
    common = dict(split=args.split, scenes=scenes, max_images=args.max_images, vsd=not args.no_vsd,
                  progress=not args.quiet, out_dir=args.out, overwrite=args.overwrite, labels=args.labels,
                  tracking=True if args.tracking else None, task=args.task,
                  grasp_tolerance=args.grasp_tolerance)
    if args.results:
        if args.opt:
            raise ConfigError("--opt applies to --estimator, not to --results")
        if args.workers != 1 or args.backend not in (None, "local") or args.ray_address:
            raise ConfigError("--workers, --backend and --ray-address apply to --estimator, not to --results")
        report = score_results(args.results, args.data, **common)
    else:
        backend, stats = backend_from_args(args), RunStats()
        try:
            timeout = AUTO_TIMEOUT if args.timeout is None else args.timeout
            report = evaluate(args.data, args.estimator, targets=args.targets or "gt-masks",
                              estimator_options=parse_options(args.opt), timeout=timeout,
                              fail_fast=args.fail_fast, backend=backend, stats=stats, **common)
        except EstimatorError as exc:
            print(f"simtest eval: estimator failed (--fail-fast): {exc}", file=sys.stderr)
            return 1
        if not args.quiet:
            print(f"simtest eval: {stats.summary()}", file=sys.stderr)
    if shown:
        report.settings["show_metrics"] = shown
    print(format_table(report))
    print(overall_table(report))
    if report.tracking is not None:
        from simtest.evaluation.tracking import tracking_table

        print()
        print(tracking_table(report.tracking))
    print()
    for name, path in report.paths.items():
        print(f"{name:<9} {path}")
    failures = report.paths.get("failures", "failures.csv")
    if report.all_images_failed():
        print(f"simtest eval: error: {report.failure_summary()}; see {failures}", file=sys.stderr)
        return 1
    if report.failures:
        print(f"simtest eval: {report.failure_summary()}; see {failures}", file=sys.stderr)
    return 0
