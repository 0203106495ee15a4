"""``simtest eval``: run a pose estimator over a BOP dataset, or score an existing BOP results CSV."""

from __future__ import annotations

import argparse
from typing import Any

from simtest.errors import ConfigError


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "eval",
        help="run a pose estimator on a BOP dataset (or score a BOP results CSV) and print the metrics",
        description="Run an estimator (built-in name: oracle, icp, umeyama; or module:attr) over a BOP dataset, "
                    "or score a results CSV written by any estimator (--results). Writes results.csv (BOP "
                    "format), metrics.json, errors.csv, failures.csv and metrics.md to --out.",
    )
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--estimator", metavar="NAME|module:attr", help="estimator to run")
    src.add_argument("--results", metavar="FILE", help="BOP results CSV to score instead of running an estimator")
    p.add_argument("--data", required=True, metavar="DATASET", help="BOP dataset folder")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--opt", action="append", default=[], metavar="KEY=VALUE",
                   help="estimator option (repeatable); values parse as int, float, bool (true/false), none, "
                        "else string; e.g. --opt rot_noise_deg=5")
    p.add_argument("--targets", default="gt-masks", choices=("gt-masks", "none"),
                   help="give the estimator the ground-truth targets and visible masks (default), or nothing")
    p.add_argument("--split", default="train_pbr", help="split folder (default: train_pbr)")
    p.add_argument("--scenes", metavar="ID,ID", help="scene ids to evaluate (default: all)")
    p.add_argument("--max-images", type=int, metavar="N", help="evaluate only the first N images")
    p.add_argument("--no-vsd", action="store_true", help="skip VSD (faster; AR is then mean of MSSD and MSPD)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--timeout", type=float, default=120.0, metavar="SECONDS",
                   help="time limit of the estimator per image (default 120; 0 = none); an image over it is "
                        "recorded in failures.csv as 'timeout' and the run goes on")
    p.set_defaults(func=run)


def parse_value(text: str) -> Any:
    """``"3"`` -> 3, ``"0.5"`` -> 0.5, ``"true"``/``"false"`` -> bool, ``"none"`` -> None, else the string."""
    low = text.strip().lower()
    if low in ("true", "yes", "on"):
        return True
    if low in ("false", "no", "off"):
        return False
    if low in ("none", "null"):
        return None
    for cast in (int, float):
        try:
            return cast(text)
        except ValueError:
            pass
    return text


def parse_options(items: list[str]) -> dict[str, Any]:
    """``["k=v", ...]`` -> ``{k: parse_value(v)}``.

    Raises:
        ConfigError: An item without ``=`` or with an empty key.
    """
    out: dict[str, Any] = {}
    for item in items:
        key, sep, value = item.partition("=")
        if not sep or not key.strip():
            raise ConfigError(f"--opt must be KEY=VALUE, got {item!r}")
        out[key.strip().replace("-", "_")] = parse_value(value)
    return out


def run(args: argparse.Namespace) -> int:
    from simtest.eval import evaluate, format_table, overall_table, score_results

    scenes = None
    if args.scenes:
        try:
            scenes = [int(s) for s in args.scenes.split(",") if s.strip()]
        except ValueError:
            raise ConfigError(f"--scenes must be comma-separated integers, got {args.scenes!r}") from None
    common = dict(split=args.split, scenes=scenes, max_images=args.max_images, vsd=not args.no_vsd,
                  progress=not args.no_progress, out_dir=args.out)
    if args.results:
        if args.opt:
            raise ConfigError("--opt applies to --estimator, not to --results")
        report = score_results(args.results, args.data, **common)
    else:
        report = evaluate(args.data, args.estimator, targets=args.targets,
                          estimator_options=parse_options(args.opt), timeout=args.timeout, **common)
    print(format_table(report))
    print(overall_table(report))
    print()
    for name, path in report.paths.items():
        print(f"{name:<9} {path}")
    return 0
