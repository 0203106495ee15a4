"""One writer per output folder: an exclusive OS file lock held for a whole run.

:func:`output_lock` takes ``flock(LOCK_EX | LOCK_NB)`` on a lock file beside the folder (``PARENT/.NAME.simtest-lock``,
so the folder itself stays exactly what the command writes). The kernel releases the lock when the process ends,
however it ends (``kill -9`` included), so a lock is never stale; the file left behind by a killed run is taken
over by the next one. A second run on the same folder is refused at once with who holds it (command, pid, host,
start time), read from the lock file. On a cluster the driver process holds the lock; the folder must be on a
file system whose ``flock`` is seen by every writer (local disks; NFS v4 maps ``flock`` to byte-range locks).
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import socket
import sys
import time
from collections.abc import Iterator
from pathlib import Path

from simtest.errors import DatasetError

__all__ = ["OutputBusyError", "output_lock", "lock_path", "LOCK_SUFFIX"]

#: Ending of the lock file's name (``.NAME`` + this, next to the folder NAME).
LOCK_SUFFIX = ".simtest-lock"


class OutputBusyError(DatasetError):
    """The output folder is being written by another running simtest process."""


def lock_path(folder: str | os.PathLike) -> Path:
    """The lock file of ``folder``: ``PARENT/.NAME.simtest-lock`` (of the resolved path, so two spellings of one
    folder share one lock)."""
    out = Path(folder).expanduser().resolve()
    return out.parent / f".{out.name}{LOCK_SUFFIX}"


def _holder_text(fd: int) -> str:
    """``simtest generate (pid N, started HH:MM:SS)`` from a held lock file (what is known of it)."""
    try:
        info = json.loads(os.pread(fd, 4096, 0).decode() or "{}")
    except (OSError, ValueError):
        info = {}
    who = str(info.get("command") or "another simtest process")
    bits = [f"pid {info['pid']}"] if "pid" in info else []
    if info.get("host") and info["host"] != socket.gethostname():
        bits.append(f"on {info['host']}")
    if "started" in info:
        bits.append("started " + time.strftime("%H:%M:%S", time.localtime(float(info["started"]))))
    return who + (f" ({', '.join(bits)})" if bits else "")


def _made_parents(path: Path) -> list[Path]:
    """Create the missing ancestors of ``path`` (which itself is not created); returns them, deepest first."""
    missing = []
    p = path.parent
    while not p.exists():
        missing.append(p)
        p = p.parent
    path.parent.mkdir(parents=True, exist_ok=True)
    return missing


@contextlib.contextmanager
def output_lock(folder: str | os.PathLike, command: str) -> Iterator[Path | None]:
    """Hold the exclusive lock of output folder ``folder`` while the block runs (see the module doc).

    Args:
        folder: The output folder (need not exist; missing parent folders are made for the lock file and
            removed again on release if still empty).
        command: What holds it, as a second run's message names it (``simtest generate``).

    Yields:
        The lock file's path; None when no lock file can be made there (a parent that is a file, a read-only
        parent): the command's own output-folder check then refuses the folder.

    Raises:
        OutputBusyError: Another process holds the lock; the message names it and what to do.
    """
    path = lock_path(folder)
    try:
        made = _made_parents(path)
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    except OSError:
        # No lock file can be made where the folder would go (its parent is a file, read-only, ...): the
        # command cannot write that folder either, and its own check names the problem before any work.
        yield None
        return
    while True:
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            holder = _holder_text(fd)
            os.close(fd)
            raise OutputBusyError(f"{str(folder)!r} is being written by {holder}; wait for it, or choose another "
                                  "--out") from None
        try:  # the holder before us may have removed the file after we opened it: then lock the new one
            same = os.path.samestat(os.fstat(fd), os.stat(path))
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)
        fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        info = {"command": command, "pid": os.getpid(), "host": socket.gethostname(), "started": time.time(),
                "argv": sys.argv}
        os.ftruncate(fd, 0)
        os.pwrite(fd, json.dumps(info).encode(), 0)
        yield path
    finally:
        with contextlib.suppress(OSError):
            os.unlink(path)
        os.close(fd)
        for p in made:
            with contextlib.suppress(OSError):
                p.rmdir()
