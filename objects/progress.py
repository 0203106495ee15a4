"""Progress of per-object work over an object set: a tqdm bar with ETA on stderr, one step per object, its
description naming the object being worked on, and one closing line naming the slowest object when the whole
took long.

What an object needs is computed on its first use and cached (CoACD collision parts: 4-23 s of one core each
for the LM-O scans, cached on disk; grasp candidates, 2-7 s each, kept in memory), so the first use of a set can
take minutes and a later one seconds. The bar therefore appears only when the work is slow: at once when a step
is known to compute something not cached (``step(name, slow=True)``, or :meth:`ObjectProgress.computing`
within the step), else once the work has run :data:`SHOW_AFTER_S` seconds. A bar of work that ended within
:data:`SUMMARY_MIN_S` is erased when it closes; longer work leaves its bar and one line such as
``simtest: collision parts of 8 objects took 140.2 s; slowest: obj_000010 (26.3 s)``.

As every bar of simtest, it is drawn whether or not stderr is a terminal (on a terminal its clock is also
redrawn every second during a long step), unless turned off: ``progress=False``, or with ``progress=None`` the
``simtest`` logger set to errors only, which is what every command's ``--quiet`` does
(:func:`simtest.cli.common.configure_logging`).
"""

from __future__ import annotations

import logging
import sys
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any

__all__ = ["ObjectProgress", "progress_enabled", "SHOW_AFTER_S", "SUMMARY_MIN_S"]

#: Seconds of work after which the bar appears even though no step said it would compute.
SHOW_AFTER_S = 2.0
#: Work that took longer than this (seconds) keeps its bar and ends with the line naming the slowest object.
SUMMARY_MIN_S = 10.0
#: Seconds between redraws of a shown bar while one step runs (elapsed time and the object's name stay live).
REDRAW_S = 1.0


def progress_enabled(progress: bool | None) -> bool:
    """Whether to draw: ``progress`` itself, or for ``None`` unless the ``simtest`` logger is set to errors only
    (``--quiet``)."""
    if progress is not None:
        return bool(progress)
    return logging.getLogger("simtest").getEffectiveLevel() < logging.ERROR


class ObjectProgress:
    """A progress bar over ``total`` objects, shown only when the work is slow (see the module docstring).

    Use as a context manager; time each object with :meth:`step`, or report one timed elsewhere (a worker
    process) with :meth:`advance`::

        with ObjectProgress(len(objects), "collision parts") as bar:
            for obj in objects:
                with bar.step(obj.name, slow=not cached(obj)):
                    obj.collision_parts

    Args:
        total: Number of objects.
        what: What is done to each object, for the description (``"collision parts"`` shows as
            ``collision parts: obj_000005`` while that object is worked on) and the closing line.
        progress: Draw the bar and the closing line (``None``: see :func:`progress_enabled`).
        show_after: Seconds of work after which the bar appears in any case (default :data:`SHOW_AFTER_S`).
        summary_after: Work longer than this (seconds) keeps its bar and gets the closing line (default
            :data:`SUMMARY_MIN_S`).
        file: Where to draw (default ``sys.stderr`` at the time of drawing).

    Attributes:
        times: ``(name, seconds)`` of every finished object, in order (recorded also when nothing is drawn).
    """

    def __init__(self, total: int, what: str, progress: bool | None = None, *, show_after: float | None = None,
                 summary_after: float | None = None, file: Any = None) -> None:
        self.total, self.what = int(total), what
        self.enabled = progress_enabled(progress) and self.total > 0
        self.show_after = float(SHOW_AFTER_S if show_after is None else show_after)
        self.summary_after = float(SUMMARY_MIN_S if summary_after is None else summary_after)
        self._file = file
        self.times: list[tuple[str, float]] = []
        self._bar: Any = None
        self._shown = False
        self._current = ""
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._start = time.perf_counter()

    # --- the context ------------------------------------------------------------------------------------
    def __enter__(self) -> "ObjectProgress":
        self._start = time.perf_counter()
        if self.enabled:
            self._thread = threading.Thread(target=self._watch, name="simtest-object-progress", daemon=True)
            self._thread.start()
        return self

    def __exit__(self, exc_type: object, *exc: object) -> None:
        self.close(failed=exc_type is not None)

    @property
    def seconds(self) -> float:
        """Wall time since the work started (seconds)."""
        return time.perf_counter() - self._start

    @property
    def shown(self) -> bool:
        """Whether the bar has been drawn (it may have been erased since)."""
        return self._shown

    def slowest(self) -> tuple[str, float] | None:
        """``(name, seconds)`` of the slowest finished object, or ``None`` before any."""
        return max(self.times, key=lambda t: t[1]) if self.times else None

    def summary(self) -> str:
        """The closing line: ``"<what> of N objects took T s; slowest: NAME (S s)"``."""
        slow = self.slowest()
        text = f"{self.what} of {len(self.times)} objects took {self.seconds:.1f} s"
        return text + (f"; slowest: {slow[0]} ({slow[1]:.1f} s)" if slow else "")

    # --- steps --------------------------------------------------------------------------------------------
    @contextmanager
    def step(self, name: str, slow: bool = False) -> Iterator[None]:
        """Time the work on one object named ``name`` (shown in the description while it runs).

        Args:
            name: The object's name.
            slow: The caller knows this step computes something not cached: show the bar now.
        """
        start = time.perf_counter()
        with self._lock:
            self._current = name
            if self._bar is not None:
                self._bar.set_description_str(self._description(), refresh=True)
            elif slow or self.seconds >= self.show_after:
                self._show()
        yield  # an error (or Ctrl-C) leaves the object uncounted, named in the bar that stays
        self.advance(name, time.perf_counter() - start)

    def computing(self) -> None:
        """The running step computes something not cached (a decomposition): show the bar now."""
        with self._lock:
            self._show()

    def advance(self, name: str, seconds: float) -> None:
        """Count one finished object, ``name``, that took ``seconds``."""
        with self._lock:
            self.times.append((name, float(seconds)))
            if self._bar is not None:
                self._bar.set_postfix_str(f"last: {name} {seconds:.1f} s", refresh=False)
                self._bar.update(1)

    def close(self, failed: bool = False) -> None:
        """Stop drawing: erase a bar of short work, keep that of long work and write the closing line.

        Args:
            failed: The work stopped on an error: a drawn bar stays (naming the object it stopped at) and no
                closing line is written.
        """
        self._stop.set()
        if self._thread is not None:
            self._thread.join()
            self._thread = None
        with self._lock:
            long = self.seconds >= self.summary_after
            if self._bar is not None:
                self._bar.leave = long or failed
                self._bar.close()
                self._bar = None
            if self.enabled and long and self.times and not failed:
                self._write(f"simtest: {self.summary()}")
            self.enabled = False

    # --- drawing --------------------------------------------------------------------------------------------
    def _description(self) -> str:
        return f"{self.what}: {self._current}" if self._current else self.what

    def _show(self) -> None:
        """Draw the bar (lock held) if it is not drawn yet."""
        if self._bar is not None or not self.enabled:
            return
        from tqdm import tqdm

        bar = tqdm(total=self.total, initial=len(self.times), desc=self._description(), unit="obj",
                   file=self._file or sys.stderr, dynamic_ncols=True, smoothing=0.0, mininterval=0.0, delay=1e9)
        # elapsed time, rate and ETA over all the work, the objects done before the bar appeared included
        bar.initial, bar.start_t = 0, time.time() - self.seconds  # tqdm keeps time.time()
        bar.delay = 0.0
        bar.refresh()
        self._bar, self._shown = bar, True

    def _watch(self) -> None:
        """Show the bar after ``show_after`` seconds; on a terminal, then redraw it every :data:`REDRAW_S` until
        closed (CoACD releases the GIL, so the elapsed time keeps moving during a long decomposition; a log file
        gets a line per finished object only)."""
        if self._stop.wait(max(0.0, self.show_after - self.seconds)):
            return
        with self._lock:
            self._show()
        stream = self._file or sys.stderr
        if not (hasattr(stream, "isatty") and stream.isatty()):
            return
        while not self._stop.wait(REDRAW_S):
            with self._lock:
                if self._bar is not None:
                    self._bar.refresh()

    def _write(self, line: str) -> None:
        from tqdm import tqdm

        tqdm.write(line, file=self._file or sys.stderr)
