"""The ``simtest`` command line: parsing and printing only; every command calls a library function.

Each sub-command lives in its own module of this package and exposes ``register(subparsers)``, which adds
its parser (with :func:`simtest.cli.common.common_parser` as parent: ``--quiet``, ``-v``) and sets ``func``
(called with the parsed namespace, returning an exit code). Errors are one line on stderr with exit code 2:
every :class:`SimtestError` and, as a backstop, every ``OSError`` (a path that cannot be read or written).
"""

from __future__ import annotations

import argparse
import importlib
import logging
import os
import sys

from simtest import __version__
from simtest.cli.common import configure_logging
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
        importlib.import_module(f"simtest.cli.{name}").register(sub)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    configure_logging(getattr(args, "verbose", 0))
    if getattr(args, "no_progress", False):
        args.quiet = True
        logging.getLogger("simtest.cli").warning("--no-progress is deprecated; use --quiet")
    try:
        code = int(args.func(args) or 0)
        sys.stdout.flush()  # a closed pipe shows up here, not at interpreter exit
        return code
    except SimtestError as exc:
        print(f"simtest {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        # The reader went away (``simtest objects list | head -1``): the Python docs' recipe, so that the
        # interpreter's final flush of stdout does not fail again.
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 1
    except OSError as exc:  # a path the library did not check first: still one line, no traceback
        print(f"simtest {args.command}: error: {_os_error_text(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"simtest {args.command}: interrupted", file=sys.stderr)
        return 130


def _os_error_text(exc: OSError) -> str:
    """``'PATH': problem`` for an OSError with a file name, else its message."""
    if exc.filename is None:
        return str(exc)
    text = f"{str(exc.filename)!r}: {(exc.strerror or str(exc)).lower()}"
    return text if exc.filename2 is None else f"{text} (with {str(exc.filename2)!r})"


if __name__ == "__main__":
    sys.exit(main())
