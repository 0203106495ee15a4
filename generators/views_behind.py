"""Finishing each rendered view (annotation, writing) on a helper thread while the next view renders."""

from __future__ import annotations

import logging

__all__ = ["ViewsBehind"]

log = logging.getLogger(__name__)


class ViewsBehind:
    """Finishes a rendered view (annotation, writing) on a helper thread while the next view renders.

    Rendering spends much of a frame in single-threaded steps (scene update, pixel read-back) that leave a
    core idle; the annotation of the view before fills it. One view is in flight at a time, views finish in
    order, and each is annotated from the scene's state when it was rendered (:meth:`SimScene.state`), so the
    output is the same as finishing every view before rendering the next. An error in a view's work is
    raised by the next :meth:`submit` or by :meth:`close`.
    """

    #: Name prefix of the helper thread (benchmarks group CPU time by it).
    THREAD_NAME = "simtest-view-behind"

    def __init__(self, threaded: bool = True) -> None:
        from concurrent.futures import ThreadPoolExecutor

        self._pool = ThreadPoolExecutor(1, thread_name_prefix=self.THREAD_NAME) if threaded else None
        self._pending = None

    def submit(self, fn, *args) -> None:
        """Wait for the view in flight (raising its error), then start ``fn(*args)`` (run it now when not
        ``threaded``)."""
        self.wait()
        if self._pool is None:
            fn(*args)
        else:
            self._pending = self._pool.submit(fn, *args)

    def wait(self) -> None:
        """Wait for the view in flight; raise its error."""
        pending, self._pending = self._pending, None
        if pending is not None:
            pending.result()

    def close(self) -> None:
        try:
            self.wait()
        finally:
            if self._pool is not None:
                self._pool.shutdown(wait=True)

    def __enter__(self) -> "ViewsBehind":
        return self

    def __exit__(self, exc_type, *exc) -> None:
        try:
            self.close()
        except Exception:
            if exc_type is None:
                raise
            # already failing: the view in flight has ended; the first error is the one raised
            log.debug("error in the view finished behind a failure", exc_info=True)
