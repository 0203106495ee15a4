"""``simtest demo``: the main job end to end on the built-in defaults, a few minutes on 2 cores.

Generates a small BOP dataset of the built-in objects, runs the demo robustness sweep on it (two noisy
oracles and ICP; clean, occlusion L1-L3, brightness/frost/snow/fog at severity 4, RealSense-like depth noise; a few
closed-loop grasp episodes per cell) and prints where the dataset and the report are.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

from simtest.cli.common import common_parser, locks_output


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser("demo", parents=[common_parser()],
                       help="generate a small dataset, run the demo robustness sweep, print the report path")
    p.add_argument("--out", default="demo_out", help="output folder (default: demo_out)")
    p.add_argument("--episodes", type=int, default=None, help="grasp episodes per cell (default 3; 0 = none)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--resume", action="store_true", help="continue a previous demo in --out")
    g.add_argument("--overwrite", action="store_true", help="discard the contents of a non-empty --out")
    p.add_argument("--fresh", dest="overwrite", action="store_true", help=argparse.SUPPRESS)  # old name
    p.set_defaults(func=run)
    locks_output(p)


def run(args: argparse.Namespace) -> int:
    from simtest.io.dataset import describe_dataset
    from simtest.sweeps.grid import DEMO_SWEEP, SweepConfig, run_sweep

    out = Path(args.out)
    data = json.loads(json.dumps(DEMO_SWEEP))
    if args.episodes is not None:
        data["grasp"]["episodes"] = args.episodes
    cfg = SweepConfig.from_dict(data, source="demo sweep")
    t0 = time.perf_counter()
    rep = run_sweep(cfg, out, resume=args.resume, overwrite=args.overwrite, progress=not args.quiet)
    print((out / "tables.md").read_text())
    print(describe_dataset(out / "data" / "clean"))
    print(f"\ndemo finished in {time.perf_counter() - t0:.0f} s ({len(rep.cells_run)} cells computed, "
          f"{len(rep.cells_skipped)} reused)")
    print(f"dataset: {(out / 'data' / 'clean').resolve()}")
    print(f"report:  {rep.paths['report'].resolve()}")
    return 0
