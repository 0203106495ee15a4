"""``simtest sweep CONFIG --out DIR``: the robustness grid (occlusion, corruptions, depth noise, depth sensors,
render conditions) for pose metrics and grasp success, resumable, with tables and a self-contained HTML report
(docs/sweeps.md)."""

from __future__ import annotations

import argparse
import dataclasses
import sys

from simtest.cli.common import add_backend_options, common_parser, locks_output


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("sweep", parents=[common_parser()], help="run a robustness sweep and write tables and report.html",
                       description="Run every (estimator, condition) cell of a sweep config (TOML or JSON; see "
                                   "configs/sweep-demo.toml, configs/sweep-renderers.toml and docs/sweeps.md) and "
                                   "write results.csv, summary.csv, tables.md and report.html. Render and "
                                   "depth-sensor conditions generate the clean scenes again and must keep their "
                                   "ground truth. Finished cells are cached: --resume continues an interrupted "
                                   "sweep without recomputing them.")
    p.add_argument("config", help="sweep config file (.toml or .json)")
    p.add_argument("--out", required=True, help="output folder")
    add_backend_options(p, "cell", workers="the config's `workers`")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--resume", action="store_true", help="continue the sweep in --out")
    g.add_argument("--overwrite", action="store_true", help="replace the contents of --out")
    p.set_defaults(func=run)
    locks_output(p)


def run(args: argparse.Namespace) -> int:
    from simtest.sweeps.grid import load_sweep_config, run_sweep

    cfg = load_sweep_config(args.config)
    where = {k: v for k, v in (("backend", args.backend), ("ray_address", args.ray_address)) if v is not None}
    if where:
        cfg = dataclasses.replace(cfg, **where)
        cfg.validate("command line")
    rep = run_sweep(cfg, args.out, resume=args.resume, overwrite=args.overwrite, progress=not args.quiet)
    if not args.quiet:
        print(rep.run.summary(), file=sys.stderr)
    print((rep.out_dir / "tables.md").read_text())
    print(f"cells: {len(rep.cells_run)} computed, {len(rep.cells_skipped)} reused, {rep.seconds:.0f} s")
    for name, path in rep.paths.items():
        print(f"{name}: {path.resolve()}")
    return 0
