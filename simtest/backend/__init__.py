"""Where units of work run: in this process, a local pool of worker processes, or a Ray cluster.

A command splits its job into *units* (a scene, an image shard, an episode, a sweep cell), each seeded from the
run's seed and its own index only, so the result of a unit does not depend on where, when or next to what it
runs: the same seed gives the same bytes with one worker, a local pool or Ray. :func:`run_units` runs the units
and yields their results as they finish; the caller accounts them (progress bar, files, tables).

Back ends:

``local``
    ``workers`` processes on this machine (``multiprocessing`` *spawn*: GL contexts do not survive fork; one
    unit in flight per worker), or this process when ``workers`` is 1. A worker process that dies without an
    exception (killed, out of memory, a native library aborting) breaks the pool: the unit it held is
    submitted again on a new pool, up to ``retries`` times, as on Ray (when the pool held several, each runs
    again alone first, so that only the unit whose worker died is charged); the run never waits on a dead
    worker.
``ray``
    Ray tasks (the ``ray`` extra, imported lazily). Without an address a local Ray instance is started with
    ``workers`` CPUs and stopped at the end; with ``address`` (``auto``, ``HOST:PORT`` or ``ray://HOST:PORT``)
    the driver joins that cluster and uses all of its CPUs (``ray://`` needs Ray Client, ``ray[client]``; without
    it the address is refused at once). :func:`preflight` joins and checks the cluster before a command writes
    anything; a join that fails is one :class:`BackendError` line naming the address, what answered and the fix.
    Each Ray worker process runs the unit's initialiser
    once (loading objects, creating its own GL context lazily) and keeps it for the units it runs next. A unit
    whose worker or node is lost is submitted again, up to ``retries`` times; the count of retried and failed
    units is in :class:`RunStats`. An exception raised *by the unit's code* is not retried: it is raised in the
    driver as it would be locally.

Why a home-made wrapper and not ``ray.util.multiprocessing.Pool``: the pool hides retries and lost workers and
starts one actor per CPU up front; units here are coarse (seconds each), so plain tasks with a bounded number in
flight are simpler, report what was retried, and let a cluster scale past the driver's own CPU count.
"""

from simtest.backend.units import (BACKENDS, DEFAULT_RETRIES, RUN_FIELDS, Backend, BackendError, RunStats, UnitFailure,
                                   check_backend, preflight, run_units, session)

__all__ = ["BACKENDS", "RUN_FIELDS", "Backend", "RunStats", "UnitFailure", "BackendError", "run_units", "check_backend",
           "preflight", "session", "DEFAULT_RETRIES"]
