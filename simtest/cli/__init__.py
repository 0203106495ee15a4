"""The ``simtest`` command line: parsing and printing only; every command calls a library function.

Each sub-command lives in its own module of this package and exposes ``register(subparsers)``, which adds
its parser (with :func:`simtest.cli.common.common_parser` as parent: ``--quiet``, ``-v``) and sets ``func``
(called with the parsed namespace, returning an exit code). Errors are one line on stderr with exit code 2:
every :class:`SimtestError` and, as a backstop, every ``OSError`` (a path that cannot be read or written).
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import importlib
import os
import re
import shutil
import sys
from pathlib import Path

from simtest import __version__
from simtest.cli.common import configure_logging
from simtest.errors import SimtestError
from simtest.io.lock import output_lock

#: Sub-command modules, in the order ``simtest --help`` lists them.
COMMAND_MODULES = ["objects", "generate", "corrupt", "eval", "pool", "grasp", "train", "export", "sweep", "adapt",
                   "bench", "demo", "show", "masks", "tolerance", "calibrate"]


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
    if getattr(args, "no_progress", False):
        args.quiet = True
        print(f"simtest {args.command}: --no-progress is deprecated; use --quiet", file=sys.stderr)
    configure_logging(getattr(args, "verbose", 0), getattr(args, "quiet", False))
    previous = _exit_on_sigterm()
    try:
        folder = getattr(args, "output_folder", None)
        folder = folder(args) if folder is not None else None
        with output_lock(folder, f"simtest {args.command}") if folder else contextlib.nullcontext():
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
        if exc.errno in (errno.ENOSPC, errno.EDQUOT):
            print(f"simtest {args.command}: error: {disk_full_text(exc, args)}", file=sys.stderr)
        else:
            print(f"simtest {args.command}: error: {_os_error_text(exc)}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"simtest {args.command}: interrupted", file=sys.stderr)
        return 130
    except _Terminated:
        print(f"simtest {args.command}: terminated", file=sys.stderr)
        return 143
    finally:
        _restore_sigterm(previous)


class _Terminated(BaseException):
    """SIGTERM, raised where the command is, so that its clean-up runs (workers stopped, locks released)."""


def _exit_on_sigterm():
    """Make SIGTERM raise :class:`_Terminated` (main thread only); returns the previous handler (None: unchanged)."""
    import signal

    def on_term(signum, frame):
        raise _Terminated()

    try:
        return signal.signal(signal.SIGTERM, on_term)
    except ValueError:  # not the main thread: leave it
        return None


def _restore_sigterm(previous) -> None:
    if previous is not None:
        import signal

        signal.signal(signal.SIGTERM, previous)


def _os_error_text(exc: OSError) -> str:
    """``'PATH': problem`` for an OSError with a file name, else its message."""
    if exc.filename is None:
        return str(exc)
    text = f"{str(exc.filename)!r}: {(exc.strerror or str(exc)).lower()}"
    return text if exc.filename2 is None else f"{text} (with {str(exc.filename2)!r})"


def _partial_owner(path: Path) -> Path:
    """``path`` cut at a writer's private partial folder (``.000003.k2j4.partial``), named as what it becomes
    (``000003``): the scene, shard or cell that was being written."""
    parts = list(path.parts)
    for i, part in enumerate(parts):
        m = re.fullmatch(r"\.(.+?)\.[^.]+\.partial", part)
        if m:
            return Path(*parts[:i], m.group(1))
    return path


def disk_full_text(exc: OSError, args: argparse.Namespace) -> str:
    """``no space left on device while writing WHAT (N MB free); free space and rerun with --resume``: what was
    being written (the file's scene or shard, else the output folder), the space left there and the next step."""
    target = Path(exc.filename) if exc.filename else None
    out = getattr(args, "out", None)
    where = _partial_owner(target) if target is not None else (Path(out) if out else None)
    probe = where
    while probe is not None and not probe.exists() and probe != probe.parent:
        probe = probe.parent
    free = ""
    if probe is not None:
        with contextlib.suppress(OSError):
            free = f" ({shutil.disk_usage(probe).free / 1e6:.0f} MB free)"
    what = "no space left on device" if exc.errno == errno.ENOSPC else "disk quota exceeded"
    resume = " with --resume" if hasattr(args, "resume") else ""
    place = f" while writing {where}" if where is not None else ""
    return f"{what}{place}{free}; free space and rerun{resume}"


if __name__ == "__main__":
    sys.exit(main())
