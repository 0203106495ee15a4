"""Running units locally or on Ray (:func:`run_units`, :func:`preflight`, :func:`session`); the contract they share
(:class:`Backend`, :class:`RunStats`, ...) is :mod:`simtest.backend.contract`; see :mod:`simtest.backend`."""

from __future__ import annotations

import logging
import multiprocessing as mp
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any

from simtest.backend.contract import (BACKENDS, DEFAULT_RETRIES, RUN_FIELDS, Backend, BackendError, RunStats,
                                      UnitFailure, check_backend)

__all__ = ["BACKENDS", "RUN_FIELDS", "DEFAULT_RETRIES", "Backend", "RunStats", "UnitFailure", "BackendError",
           "run_units", "check_backend", "session", "preflight"]


def run_units(fn: Callable[[Any], Any], units: Sequence[Any], backend: Backend, *,
              init: Callable[..., None] | None = None, init_args: tuple = (),
              stats: RunStats | None = None) -> Iterator[Any]:
    """Run ``fn(unit)`` for every unit and yield the results in the order they finish.

    Args:
        fn: A module-level function (picklable by reference) that runs one unit; it may read the state the
            initialiser set up in its process.
        units: Picklable unit descriptions (small: an index and a folder, say).
        backend: Where to run them.
        init: Module-level function run once per worker process before its first unit (not called when the
            units run in this process: the caller has its state at hand then).
        init_args: Picklable arguments of ``init``.
        stats: Filled with the counts of finished, retried and failed units.

    Raises:
        BackendError: The ``ray`` extra is missing or the cluster cannot be reached; or units were lost beyond
            their retries (raised after every other unit has finished and been yielded).
        Exception: Whatever ``fn`` raised, unchanged (the run stops there, as it does locally).
    """
    stats = stats if stats is not None else RunStats()
    stats.backend = backend.name
    if backend.is_ray:
        from simtest.backend.ray_cluster import run_ray

        yield from run_ray(fn, list(units), backend, init, init_args, stats)
    elif backend.in_process(len(units)):
        for unit in units:
            yield fn(unit)
            stats.finished += 1
    else:
        yield from _run_local_pool(fn, list(units), backend, init, init_args, stats)
    if stats.failures:
        lost = ", ".join(repr(f.unit) for f in stats.failures[:10])
        raise BackendError(f"{len(stats.failures)} unit(s) were lost with their workers more than "
                           f"{backend.retries} time(s): {lost}; first error: {stats.failures[0].message}")


def _run_local_pool(fn: Callable[[Any], Any], units: list[Any], backend: Backend, init, init_args: tuple,
                    stats: RunStats) -> Iterator[Any]:
    """The units on ``backend.workers`` spawned processes, at most one unit in flight per worker. A worker that
    dies without an exception (killed, out of memory, a native library aborting) breaks the pool, and the pool
    does not say whose unit it was: when it held one unit, that unit is charged a loss and submitted again, up to
    ``backend.retries`` losses (then a :class:`UnitFailure`); when it held several, none is charged and each is
    submitted again alone, one at a time, so that the next break names its unit. The finished ones are kept."""
    from concurrent.futures import FIRST_COMPLETED, wait
    from concurrent.futures.process import BrokenProcessPool

    ctx = mp.get_context("spawn")  # GL contexts do not survive fork
    todo, alone = list(range(len(units))), []  # alone: suspects of a break, run one at a time
    losses: dict[int, int] = {}
    while todo or alone:
        solo = bool(alone)
        workers = 1 if solo else min(backend.workers, len(todo))
        with _pool(workers, ctx, init, init_args) as pool:
            queue, alone, todo = (alone, [], todo) if solo else (todo, alone, [])
            in_flight: dict[Any, int] = {}
            while queue or in_flight:
                while queue and len(in_flight) < workers:
                    i = queue.pop(0)
                    in_flight[pool.submit(_run_unit, fn, units[i])] = i
                done, _ = wait(in_flight, return_when=FIRST_COMPLETED)
                broken, held = None, []
                for future in done:
                    i = in_flight.pop(future)
                    try:
                        result = future.result()
                    except BrokenProcessPool as exc:
                        broken = exc
                        held.append(i)
                        continue
                    stats.finished += 1
                    yield result
                if broken is not None:  # the pool is gone: what it held and what was left go to a new one
                    held += list(in_flight.values())
                    if len(held) == 1:
                        _lost(units, held[0], broken, losses, backend.retries, todo, stats)
                    else:
                        _suspects(units, held, alone, stats)
                    (alone if solo else todo).extend(queue)
                    break


@contextmanager
def _pool(workers: int, ctx, init, init_args: tuple) -> Iterator[Any]:
    """A process pool of ``workers`` spawned workers whose processes are terminated if the run stops early
    (Ctrl-C, SIGTERM raised as an exception, an error in the driver, the consumer closing the generator): no
    worker outlives the run."""
    from concurrent.futures import ProcessPoolExecutor

    with ProcessPoolExecutor(workers, mp_context=ctx, initializer=_init_worker, initargs=(init, init_args)) as pool:
        try:
            yield pool
        except BaseException:
            _stop_workers(pool)
            raise


def _stop_workers(pool) -> None:
    """Terminate ``pool``'s worker processes now (their units are abandoned) and let the pool go without waiting:
    otherwise the pool's exit waits for units that may run for hours, and a killed driver leaves them orphaned."""
    stop = getattr(pool, "terminate_workers", None)  # Python 3.14
    if callable(stop):
        stop()
        return
    for process in list((getattr(pool, "_processes", None) or {}).values()):
        process.terminate()
    pool.shutdown(wait=False, cancel_futures=True)


#: An exception the worker's initialiser raised, re-raised by its first unit (so the driver gets it as it is,
#: rather than a pool broken by a worker that exited during start-up).
_INIT_ERROR: list[BaseException] = []


def _init_worker(init: Callable[..., None] | None, init_args: tuple) -> None:
    if init is not None:
        try:
            init(*init_args)
        except Exception as exc:  # noqa: BLE001 (handed to the first unit, raised in the driver)
            _INIT_ERROR.append(exc)


def _run_unit(fn: Callable[[Any], Any], unit: Any) -> Any:
    if _INIT_ERROR:
        raise _INIT_ERROR[0]
    return fn(unit)


def _lost(units: list[Any], i: int, exc: BaseException, losses: dict[int, int], retries: int, todo: list[int],
          stats: RunStats) -> None:
    """Charge unit ``i`` a loss: submit it again (``todo``) or, past ``retries``, record its failure."""
    losses[i] = losses.get(i, 0) + 1
    if losses[i] > retries:
        stats.failures.append(UnitFailure(units[i], f"a worker process died while running it ({exc})"))
    else:
        stats.retried += 1
        todo.append(i)
        logging.getLogger(__name__).warning(f"unit {units[i]!r} lost its worker process (it died without an "
                                            f"exception); submitted again ({losses[i]} of {retries} retries)")


def _suspects(units: list[Any], held: list[int], alone: list[int], stats: RunStats) -> None:
    """Units ``held`` by a pool that broke: one of them, unknown which, lost its worker; each runs again alone."""
    for i in held:
        stats.retried += 1
        alone.append(i)
        logging.getLogger(__name__).warning(f"unit {units[i]!r} lost its worker process with {len(held) - 1} other "
                                            f"unit(s) in flight; submitted again alone to find whose it was")


def preflight(backend: Backend) -> None:
    """Join (or start) the Ray instance ``backend`` asks for and check it, before a command creates or touches
    its output: the ``ray`` extra (and for ``ray://`` Ray Client) installed, a Ray head answering at
    ``backend.address`` that lets this driver in, alive nodes with CPUs, the same simtest version on every node.
    The connection stays up for the command's :func:`run_units` / :func:`session` (which shut it down at their
    end). Nothing is checked for ``local``.

    Raises:
        BackendError: One line naming the address, what answered there and the fix.
    """
    if backend.is_ray:
        from simtest.backend.ray_cluster import connect

        connect(backend)


@contextmanager
def session(backend: Backend, stats: RunStats | None = None) -> Iterator[None]:
    """Keep one Ray instance up across several :func:`run_units` calls (a job in phases: generate, then
    corrupt, then evaluate), so it starts once; ``stats`` gets its start-up time, nodes and CPUs. A no-op for
    ``local``; a Ray already initialised in this process by the caller is used and left running."""
    if not backend.is_ray:
        yield
        return
    from simtest.backend.ray_cluster import ray_session

    with ray_session(backend, stats):
        yield
