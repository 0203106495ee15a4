"""``simtest adapt --sweep SWEEP_DIR --out DIR --images N``: fit where a sweep's estimator fails into an adapted
generation config (and its uniform control); with ``--loop`` or ``--train-config F`` also generate both, continue
training the estimator on each and rerun the sweep's pose cells (docs/adapt.md)."""

from __future__ import annotations

import argparse

from simtest.cli.common import common_parser, locks_output


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "adapt", parents=[common_parser()], help="fit generation weights where a sweep's estimator fails (and test them)",
        description="Read one estimator's per-target results of a finished sweep, bin them by condition, object, "
                    "visible fraction, camera distance, elevation and in-plane angle, and write OUT/adapted.toml "
                    "(the sweep's generation config with more mass where the failure rate's 95 %% interval is "
                    "high, a floor so no bin gets nothing), OUT/uniform.toml (the control), fit.json, fit.md and "
                    "mass.png. With --loop or --train-config: generate N images from each, continue training the "
                    "estimator's network from the same checkpoint on each with equal steps and seed, rerun the "
                    "sweep's pose cells and write adapt.json and adapt.md.")
    p.add_argument("--sweep", required=True, metavar="SWEEP_DIR", help="a finished sweep folder (simtest sweep)")
    p.add_argument("--out", required=True, metavar="DIR", help="output folder")
    p.add_argument("--images", required=True, type=int, metavar="N", help="images of the adapted and of the "
                                                                          "control dataset")
    p.add_argument("--estimator", metavar="NAME", help="the sweep's estimator to fit (default: its only one)")
    p.add_argument("--bins", type=int, default=4, help="parts of each numeric factor's range (default: 4)")
    p.add_argument("--floor", type=float, default=0.25,
                   help="share of the uniform mass every bin keeps, in (0, 1] (default: 0.25)")
    p.add_argument("--seed", type=int, help="seed of the new datasets (default: the sweep dataset's seed + 1)")
    p.add_argument("--train-config", metavar="F", help="run the loop with these training settings (TOML/JSON: "
                                                       "data, init, epochs, batch_size, lr, seed, augment, threads, "
                                                       "max_images)")
    p.add_argument("--loop", action="store_true", help="run the loop with the default training settings")
    p.add_argument("--overwrite", action="store_true", help="replace the contents of a non-empty --out")
    p.set_defaults(func=run)
    locks_output(p)


def run(args: argparse.Namespace) -> int:
    from simtest.io.files import prepare_out_dir
    from simtest.sweeps.adapt import write_fit

    loop = args.loop or args.train_config is not None
    train = None
    if loop:
        from simtest.sweeps.adapt_loop import load_train_config

        train = load_train_config(args.train_config)  # before the output folder is touched
    prepare_out_dir(args.out, overwrite=args.overwrite, clear=True, protect=[args.sweep], what="adapt folder")
    fit = write_fit(args.sweep, args.out, args.images, args.estimator, bins=args.bins, floor=args.floor,
                    seed=args.seed)
    print(f"fitted {fit.estimator} on {fit.targets} targets")
    for name in ("adapted", "uniform"):
        print(f"{name}: {getattr(fit, name).resolve()}")
    print(f"figure: {(fit.out / 'mass.png').resolve()}")
    if train is not None:
        from simtest.sweeps.adapt_loop import run_loop

        result = run_loop(fit, train, progress=not args.quiet)
        print((fit.out / "adapt.md").read_text())
        print(f"adapt.json: {(fit.out / 'adapt.json').resolve()} ({result['wall_s']:.0f} s)")
    return 0
