"""What every ``simtest`` command shares: the ``--quiet`` and ``-v/--verbose`` switches (one parent parser),
logging set-up, and choices read lazily from the library (so ``simtest --help`` imports nothing heavy)."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Callable
from typing import Any
import importlib
import logging
from collections.abc import Iterator

__all__ = ["common_parser", "add_no_progress_alias", "add_fault_options", "add_backend_options", "configure_logging",
           "CommandLineFormatter", "LazyChoices"]


def common_parser() -> argparse.ArgumentParser:
    """The parent parser of every command: ``--quiet`` (no progress bars) and ``-v``/``-vv`` (log level)."""
    p = argparse.ArgumentParser(add_help=False)
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.add_argument("-v", "--verbose", action="count", default=0,
                   help="log more on stderr: -v info, -vv debug (default: warnings and errors only)")
    return p


def add_no_progress_alias(parser: argparse.ArgumentParser) -> None:
    """Keep ``--no-progress`` working (hidden, deprecated): :func:`simtest.cli.main` turns it into ``--quiet``."""
    parser.add_argument("--no-progress", dest="no_progress", action="store_true", help=argparse.SUPPRESS)


def add_fault_options(parser: argparse.ArgumentParser, unit: str, over_limit: str, goes_on: str,
                      declared: bool = False) -> None:
    """``--timeout SECONDS`` and ``--fail-fast``, the estimator-fault options of eval and grasp.

    Args:
        unit: What one estimator call covers (``"image"``, ``"episode"``).
        over_limit: What happens to a unit over the time limit (help text).
        goes_on: When the command exits 1 without ``--fail-fast`` (help text).
        declared: Without ``--timeout`` the value is None: 120 s, or the estimator's declared ``time_limit_s``
            where longer (:func:`simtest.estimators.guard.resolve_timeout`); else the default is 120.
    """
    default = "120, or the estimator's own limit where it declares a longer one" if declared else "120"
    parser.add_argument("--timeout", type=float, default=None if declared else 120.0, metavar="SECONDS",
                        help=f"time limit of the estimator per {unit} (default {default}; 0 = none); {over_limit}")
    parser.add_argument("--fail-fast", action="store_true",
                        help=f"stop at the estimator's first failure and print its traceback (exit code 1); "
                             f"without it the run goes on ({goes_on})")


def add_backend_options(parser: argparse.ArgumentParser, unit: str, workers: str = "--workers") -> None:
    """``--backend local|ray`` and ``--ray-address ADDR``: where the command's units of work run
    (:mod:`simtest.backend`). Both default to ``None`` so a config file's values stay in force.

    Args:
        unit: What one unit of work is (``"scene"``, ``"episode"``, ``"cell"``), for the help text.
        workers: What sets the number of workers, for the help text (``"--workers"``, or e.g. the config key
            of a command without that option).
    """
    parser.add_argument("--backend", choices=["local", "ray"], default=None,
                        help=f"where the {unit}s run: local (default; {workers} processes on this machine) or ray "
                             f"(Ray tasks, one {unit} each; needs simtest[ray]; see docs/distributed.md)")
    parser.add_argument("--ray-address", default=None, metavar="ADDR",
                        help="with --backend ray: join the running cluster at ADDR ('auto' on a cluster node, or "
                             "HOST:PORT of the head: the --port of `ray start --head`, 6379 by default; "
                             "ray://HOST:PORT needs ray[client]); it is joined and checked before any output is "
                             f"written; default: start a local Ray with {workers} CPUs. A head with token auth "
                             "needs RAY_AUTH_TOKEN (docs/distributed.md)")


def backend_from_args(args: argparse.Namespace):
    """The :class:`simtest.backend.Backend` that ``--backend``, ``--ray-address`` and ``--workers`` (1 when the
    command has none or it is unset) ask for.

    Raises:
        ConfigError: A bad combination, e.g. ``--ray-address`` without ``--backend ray`` or ``--workers 0``.
    """
    from simtest.backend import Backend

    workers = getattr(args, "workers", None)
    return Backend(getattr(args, "backend", None) or "local", 1 if workers is None else workers,
                   getattr(args, "ray_address", None))


class _BarSafeHandler(logging.StreamHandler):
    """Log lines to stderr through ``tqdm.write``: a running progress bar is cleared and redrawn below the line
    instead of having the line glued onto it."""

    def emit(self, record: logging.LogRecord) -> None:
        try:
            from tqdm import tqdm

            tqdm.write(self.format(record), file=sys.stderr)
        except Exception:  # noqa: BLE001 - logging must never raise
            self.handleError(record)


class CommandLineFormatter(logging.Formatter):
    """``simtest: warning: <message>``: the level in lower case and the message, no file or line of simtest's
    code. The logger's name follows the level for other libraries' records, and for every record when
    ``show_names`` (``-vv``), e.g. ``simtest: debug: simtest.objects.collision: ...``."""

    def __init__(self, show_names: bool = False) -> None:
        super().__init__()
        self.show_names = show_names

    def format(self, record: logging.LogRecord) -> str:
        line = super().format(record)
        own = record.name == "simtest" or record.name.startswith("simtest.")
        name = f"{record.name}: " if self.show_names or not own else ""
        return f"simtest: {record.levelname.lower()}: {name}{line}"


def configure_logging(verbose: int, quiet: bool = False) -> None:
    """Log records of the ``simtest`` loggers at WARNING (0), INFO (1) or DEBUG (2+) to stderr, one line each
    (:class:`CommandLineFormatter`); ``--quiet`` without ``-v``: errors only (a command's own summary lines are
    printed, not logged)."""
    handler = next((h for h in logging.getLogger().handlers if isinstance(h, _BarSafeHandler)), None)
    if handler is None:
        handler = _BarSafeHandler()
        logging.getLogger().addHandler(handler)
    handler.setFormatter(CommandLineFormatter(show_names=verbose >= 2))
    level = logging.WARNING if verbose <= 0 else logging.INFO if verbose == 1 else logging.DEBUG
    if quiet and verbose <= 0:
        level = logging.ERROR
    logging.getLogger("simtest").setLevel(level)


class LazyChoices:
    """argparse ``choices`` whose names come from a library mapping imported only when needed (a value is
    checked or the help is shown), e.g. ``LazyChoices("simtest.corrupt", "DEPTH_PRESETS")``."""

    def __init__(self, module: str, attr: str) -> None:
        self.module, self.attr = module, attr

    def names(self) -> list[str]:
        return list(getattr(importlib.import_module(self.module), self.attr))

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())

    def __contains__(self, value: object) -> bool:
        return value in self.names()

    def __len__(self) -> int:
        return len(self.names())


def locks_output(parser: argparse.ArgumentParser, folder: Callable[[argparse.Namespace], Any] | None = None) -> None:
    """Declare that the command writes an output folder (``--out`` unless ``folder`` picks another, or returns
    None when this run writes none): :func:`simtest.cli.main` holds its lock for the whole run
    (:func:`simtest.io.lock.output_lock`), so a second run on the same folder is refused before any work."""
    parser.set_defaults(output_folder=folder or (lambda args: args.out))
