"""Where units of work run: in this process, a local pool of worker processes, or a Ray cluster.

A command splits its job into *units* (a scene, an image shard, an episode, a sweep cell), each seeded from the
run's seed and its own index only, so the result of a unit does not depend on where, when or next to what it
runs: the same seed gives the same bytes with one worker, a local pool or Ray. :func:`run_units` runs the units
and yields their results as they finish; the caller accounts them (progress bar, files, tables).

Back ends:

``local``
    Today's behaviour: ``workers`` processes on this machine (``multiprocessing`` *spawn*: GL contexts do not
    survive fork), or this process when ``workers`` is 1.
``ray``
    Ray tasks (the ``ray`` extra, imported lazily). Without an address a local Ray instance is started with
    ``workers`` CPUs and stopped at the end; with ``address`` (``auto``, ``HOST:PORT`` or ``ray://HOST:PORT``)
    the driver joins that cluster and uses all of its CPUs. Each Ray worker process runs the unit's initialiser
    once (loading objects, creating its own GL context lazily) and keeps it for the units it runs next. A unit
    whose worker or node is lost is submitted again, up to ``retries`` times; the count of retried and failed
    units is in :class:`RunStats`. An exception raised *by the unit's code* is not retried: it is raised in the
    driver as it would be locally.

Why a home-made wrapper and not ``ray.util.multiprocessing.Pool``: the pool hides retries and lost workers and
starts one actor per CPU up front; units here are coarse (seconds each), so plain tasks with a bounded number in
flight are simpler, report what was retried, and let a cluster scale past the driver's own CPU count.
"""

from __future__ import annotations

import hashlib
import multiprocessing as mp
import os
import pickle
import sys
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass, field
from typing import Any

from simtest.errors import ConfigError, SimtestError

__all__ = ["BACKENDS", "RUN_FIELDS", "Backend", "RunStats", "UnitFailure", "BackendError", "run_units", "check_backend",
           "session", "preflight"]

#: Back ends :func:`run_units` knows.
BACKENDS = ("local", "ray")

#: Config fields that say where and how fast a run goes, not what it makes: a resume may change them.
RUN_FIELDS = ("workers", "backend", "ray_address")

#: Default number of times a unit whose Ray worker (or node) died is submitted again.
DEFAULT_RETRIES = 3


class BackendError(SimtestError, RuntimeError):
    """The back end cannot start (missing extra, unreachable cluster) or lost units beyond their retries."""


@dataclass(frozen=True)
class Backend:
    """Where to run units.

    Attributes:
        name: ``local`` or ``ray``.
        workers: Local worker processes, or the CPUs of a Ray instance started here (ignored when joining a
            cluster: its CPUs are used).
        address: Ray only: ``None`` starts a local instance; ``auto`` / ``HOST:PORT`` / ``ray://HOST:PORT`` joins
            a running cluster.
        retries: Ray only: times a unit whose worker died is submitted again.
    """

    name: str = "local"
    workers: int = 1
    address: str | None = None
    retries: int = DEFAULT_RETRIES

    def __post_init__(self) -> None:
        check_backend(self.name, self.address, self.workers)

    @classmethod
    def of(cls, cfg: Any) -> "Backend":
        """The back end a run config asks for (its :data:`RUN_FIELDS`: ``backend``, ``workers``,
        ``ray_address``)."""
        return cls(cfg.backend, cfg.workers, cfg.ray_address)

    @property
    def is_ray(self) -> bool:
        return self.name == "ray"

    def in_process(self, n_units: int) -> bool:
        """Whether ``n_units`` units run in this process (the local back end with one worker or one unit)."""
        return not self.is_ray and (self.workers <= 1 or n_units <= 1)

    def describe(self) -> str:
        if self.is_ray:
            return f"ray ({self.address})" if self.address else f"ray (local, {self.workers} CPUs)"
        return f"local ({self.workers} worker{'s' if self.workers != 1 else ''})"


def check_backend(name: Any, address: Any = None, workers: Any = 1) -> str:
    """``name`` if it names a back end and the other settings fit it.

    Raises:
        ConfigError: Naming the bad value and what is allowed.
    """
    if name not in BACKENDS:
        raise ConfigError(f"backend must be one of {', '.join(BACKENDS)}; got {name!r}")
    if address is not None:
        if name != "ray":
            raise ConfigError(f"ray_address {address!r} needs backend 'ray' (got backend {name!r})")
        if not isinstance(address, str) or not address.strip():
            raise ConfigError(f"ray_address must be 'auto', 'HOST:PORT' or 'ray://HOST:PORT'; got {address!r}")
    if isinstance(workers, bool) or not isinstance(workers, int) or workers < 1:
        raise ConfigError(f"workers must be an integer >= 1; got {workers!r}")
    return name


@dataclass
class UnitFailure:
    """A unit that did not finish because its worker (or node) was lost more than ``retries`` times."""

    unit: Any
    message: str


@dataclass
class RunStats:
    """What :func:`run_units` did: units finished, retried (worker lost, submitted again) and failed."""

    backend: str = "local"
    finished: int = 0
    retried: int = 0
    failures: list[UnitFailure] = field(default_factory=list)
    startup_s: float = 0.0  #: seconds to start or join the Ray instance
    cluster_cpus: int = 0

    def summary(self) -> str:
        """One line for the end of a run, e.g. ``ray: 40 units, 1 retried, 0 failed (start-up 3.1 s)``."""
        line = f"{self.backend}: {self.finished} units done, {self.retried} retried, {len(self.failures)} failed"
        if self.backend == "ray":
            line += f" (start-up {self.startup_s:.1f} s, {self.cluster_cpus} CPUs)"
        return line


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
        yield from _run_ray(fn, list(units), backend, init, init_args, stats)
    elif backend.in_process(len(units)):
        for unit in units:
            yield fn(unit)
            stats.finished += 1
    else:
        ctx = mp.get_context("spawn")  # GL contexts do not survive fork
        with ctx.Pool(min(backend.workers, len(units)), initializer=init, initargs=init_args) as pool:
            for result in pool.imap_unordered(fn, units):
                stats.finished += 1
                yield result
    if stats.failures:
        lost = ", ".join(repr(f.unit) for f in stats.failures[:10])
        raise BackendError(f"{len(stats.failures)} unit(s) were lost with their workers more than "
                           f"{backend.retries} time(s): {lost}; first error: {stats.failures[0].message}")


def preflight(backend: Backend) -> None:
    """Fail now, before a command touches its output, when ``backend`` cannot run: the ``ray`` extra missing, or
    no head node answering at ``backend.address``. Nothing is checked for ``local``.

    Raises:
        BackendError: Naming what is missing and how to get it.
    """
    if backend.is_ray:
        _ray_module()
        if backend.address is not None:
            _check_reachable(backend.address)


@contextmanager
def session(backend: Backend, stats: RunStats | None = None) -> Iterator[None]:
    """Keep one Ray instance up across several :func:`run_units` calls (a job in phases: generate, then
    corrupt, then evaluate), so it starts once; ``stats.startup_s`` gets its start-up time. A no-op for
    ``local`` and when Ray is already initialised in this process."""
    if not backend.is_ray:
        yield
        return
    ray, started = _start_ray(backend, stats if stats is not None else RunStats(backend=backend.name))
    try:
        yield
    finally:
        if started:
            ray.shutdown()


# --- Ray -------------------------------------------------------------------------------------------------
#: Initialisers already run in this (worker) process, by key.
_INITIALISED: set[str] = set()


def _init_key(init: Callable | None, init_args: tuple) -> str:
    if init is None:
        return ""
    blob = pickle.dumps((init.__module__, init.__qualname__, init_args), protocol=4)
    return hashlib.sha256(blob).hexdigest()


def _ray_unit(fn: Callable[[Any], Any], unit: Any, init: Callable | None, init_args: tuple, key: str) -> Any:
    """Body of one Ray task: the initialiser once per worker process (per distinct initialiser), then ``fn``."""
    if init is not None and key not in _INITIALISED:
        init(*init_args)
        _INITIALISED.clear()  # a worker keeps the state of one run at a time
        _INITIALISED.add(key)
    return fn(unit)


def _ray_module():
    try:
        import ray
    except ImportError as exc:
        raise BackendError("backend 'ray' needs the ray extra: pip install 'simtest[ray]'") from exc
    return ray


def _start_ray(backend: Backend, stats: RunStats):
    """Start a local Ray instance or join the cluster at ``backend.address``; returns ``(ray, started_here)``."""
    ray = _ray_module()
    t0 = time.perf_counter()
    started = False
    if not ray.is_initialized():
        env = {k: os.environ[k] for k in ("MUJOCO_GL", "PYOPENGL_PLATFORM", "SIMTEST_CACHE", "LP_NUM_THREADS")
               if k in os.environ}
        kwargs: dict[str, Any] = {"include_dashboard": False, "logging_level": "WARNING",
                                  "runtime_env": {"env_vars": env} if env else None}
        if backend.address is not None:
            _check_reachable(backend.address)
        try:
            if backend.address is None:  # "local": a new instance, never one found in RAY_ADDRESS or /tmp/ray
                ray.init(address="local", num_cpus=backend.workers, **kwargs)
            else:
                ray.init(address=backend.address, **kwargs)
        except Exception as exc:  # ConnectionError, RuntimeError, ValueError: all mean "cannot reach it"
            where = backend.address or "a local instance"
            raise BackendError(f"cannot start Ray at {where}: {type(exc).__name__}: {exc}") from exc
        started = True
    stats.startup_s = time.perf_counter() - t0
    stats.cluster_cpus = int(ray.cluster_resources().get("CPU", 0))
    return ray, started


def _check_reachable(address: str, timeout_s: float = 5.0) -> None:
    """Fail fast when ``HOST:PORT`` (or ``ray://HOST:PORT``) does not accept a connection (Ray itself waits
    minutes for an absent head node). ``auto`` is left to Ray, which fails at once when no cluster is running."""
    import socket

    hostport = address.split("://", 1)[-1]
    if address == "auto" or ":" not in hostport:
        return
    host, _, port = hostport.rpartition(":")
    try:
        with socket.create_connection((host, int(port)), timeout=timeout_s):
            pass
    except (OSError, ValueError) as exc:
        raise BackendError(f"cannot start Ray at {address}: no Ray head node answers there ({exc}); start one "
                           f"with `ray start --head` on that machine, or pass --ray-address auto on a cluster "
                           f"node") from exc


def _run_ray(fn, units: list, backend: Backend, init, init_args: tuple, stats: RunStats) -> Iterator[Any]:
    ray, started = _start_ray(backend, stats)
    from ray.exceptions import RayTaskError

    running: dict[Any, int] = {}
    try:
        task = ray.remote(num_cpus=1, max_retries=0)(_ray_unit)
        key = _init_key(init, init_args)
        args_ref = ray.put(init_args)
        window = max(1, 2 * max(stats.cluster_cpus, 1))  # units in flight: enough to keep every CPU busy
        pending = list(range(len(units)))[::-1]
        attempts = [0] * len(units)
        while pending or running:
            while pending and len(running) < window:
                i = pending.pop()
                running[task.remote(fn, units[i], init, args_ref, key)] = i
            done, _ = ray.wait(list(running), num_returns=1)
            i = running.pop(done[0])
            try:
                result = ray.get(done[0])
            except RayTaskError as exc:  # the unit's own code raised: same as locally
                cause = exc.as_instanceof_cause() if hasattr(exc, "as_instanceof_cause") else exc
                raise getattr(exc, "cause", None) or cause from None
            except Exception as exc:  # worker or node lost, object lost: submit again
                attempts[i] += 1
                if attempts[i] <= backend.retries:
                    stats.retried += 1
                    print(f"simtest: {backend.name}: unit {units[i]!r} lost its worker "
                          f"({type(exc).__name__}); retry {attempts[i]}/{backend.retries}", file=sys.stderr)
                    pending.append(i)
                else:
                    stats.failures.append(UnitFailure(units[i], f"{type(exc).__name__}: {exc}"))
                continue
            stats.finished += 1
            yield result
    finally:
        for ref in running:  # the run stopped early (an error, --fail-fast, Ctrl-C): free the cluster's CPUs
            # (best effort: Ray may still run a task whose worker was being started)
            try:
                ray.cancel(ref, force=True)
            except Exception:  # noqa: BLE001 - already finished or gone: nothing to cancel
                pass
        if started:
            ray.shutdown()
