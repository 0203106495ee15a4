"""``simtest pool RUN RUN ... --out DIR``: several evaluation runs of one estimator scored together
(:func:`simtest.evaluation.pooled.pool_runs`)."""

from __future__ import annotations

import argparse

from simtest.cli.common import common_parser


def register(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "pool", parents=[common_parser()],
        help="score several `simtest eval` runs together (unseen test sets pooled, intervals over scenes)",
        description="Pool the per-target errors of several `simtest eval` output folders (e.g. one estimator "
                    "on test sets generated with different unseen seeds): each run's score with its Wilson "
                    "interval over targets, the pooled score with a 95 % percentile-bootstrap interval over "
                    "all runs' scenes, and the spread between runs. Writes pooled.json and pooled.md.",
    )
    p.add_argument("runs", nargs="+", metavar="RUN", help="folders written by `simtest eval` (with errors.csv)")
    p.add_argument("--out", required=True, metavar="DIR", help="folder for pooled.json and pooled.md")
    p.add_argument("--overwrite", action="store_true", help="replace an existing pooled.json / pooled.md")
    p.set_defaults(func=run)


def run(args: argparse.Namespace) -> int:
    import logging
    from pathlib import Path

    from simtest.errors import ConfigError
    from simtest.evaluation.pooled import pool_runs, pooled_markdown, write_pooled

    out = Path(args.out)
    existing = [p for p in (out / "pooled.json", out / "pooled.md") if p.exists()]
    if existing and not args.overwrite:
        raise ConfigError(f"{existing[0]} exists; pass --overwrite to replace it")
    score = pool_runs(args.runs)
    if len(set(score.estimators)) > 1:
        logging.getLogger("simtest").warning(
            "the runs are of different estimators (%s): their pooled score mixes methods",
            ", ".join(sorted(set(score.estimators))))
    write_pooled(score, out)
    print(pooled_markdown(score), end="")
    print(f"\npooled  {out / 'pooled.json'}\ntable   {out / 'pooled.md'}")
    return 0
