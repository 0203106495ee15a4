"""The ``simtest`` command line: parsing and printing only; every command calls a library function.

Each sub-command lives in its own module of this package and exposes ``register(subparsers)``, which adds
its parser and sets ``func`` (called with the parsed namespace, returning an exit code).
"""

from __future__ import annotations

import argparse
import importlib
import sys

from simtest import __version__
from simtest.errors import SimtestError

#: Sub-command modules, in the order ``simtest --help`` lists them.
COMMAND_MODULES = ["objects", "generate", "corrupt", "eval", "grasp", "train", "sweep", "bench", "demo"]


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="simtest",
        description="Synthetic BOP datasets, robustness sweeps and closed-loop grasping for 6D pose estimation.",
    )
    parser.add_argument("--version", action="version", version=f"simtest {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name in COMMAND_MODULES:
        try:
            module = importlib.import_module(f"simtest.cli.{name}")
        except ModuleNotFoundError as exc:
            if exc.name == f"simtest.cli.{name}":
                continue  # command not built yet
            raise
        module.register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        return int(args.func(args) or 0)
    except SimtestError as exc:
        print(f"simtest {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"simtest {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
