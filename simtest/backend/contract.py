"""The back-end contract: where units run (:class:`Backend`), what a run did (:class:`RunStats`), a unit lost with
its worker (:class:`UnitFailure`) and the error of a back end that cannot run (:class:`BackendError`). Both ways
of running units (:mod:`simtest.backend.units` locally, :mod:`simtest.backend.ray_cluster` on Ray) read them."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from simtest.errors import ConfigError, SimtestError

__all__ = ["BACKENDS", "RUN_FIELDS", "DEFAULT_RETRIES", "Backend", "RunStats", "UnitFailure", "BackendError",
           "check_backend"]

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
        retries: Times a unit whose worker died (a lost Ray node or worker; locally a process killed or
            aborted by a native library) is submitted again.
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
    """What :func:`run_units` did: units finished, retried (worker lost, submitted again) and failed, and where
    they ran (for Ray: a cluster joined or an instance started here, its nodes and CPUs)."""

    backend: str = "local"
    finished: int = 0
    retried: int = 0
    failures: list[UnitFailure] = field(default_factory=list)
    startup_s: float = 0.0  #: seconds to start or join the Ray instance (checks included)
    cluster_cpus: int = 0
    nodes: int = 0  #: alive Ray nodes when the run began
    cluster: str = ""  #: ``joined`` (``--ray-address``), ``started`` (a local instance) or ``existing`` (found)
    address: str | None = None  #: the address joined

    def summary(self) -> str:
        """One line for the end of a run, e.g. ``ray: 40 units done, 1 retried, 0 failed (joined
        10.0.0.1:6379 in 0.9 s: 4 nodes, 64 CPUs)``."""
        line = f"{self.backend}: {self.finished} units done, {self.retried} retried, {len(self.failures)} failed"
        if self.backend == "ray":
            where = {"joined": f"joined {self.address} in {self.startup_s:.1f} s: ",
                     "started": f"local Ray instance started in {self.startup_s:.1f} s: ",
                     "existing": "Ray already initialised in this process: "}.get(self.cluster, "")
            line += f" ({where}{self.nodes} node{'s' if self.nodes != 1 else ''}, {self.cluster_cpus} CPUs)"
        return line

    def record(self, workers: int) -> dict[str, Any]:
        """What a run's record (a manifest's ``runs`` entry, a summary's ``run``) says about where it ran:
        ``backend``, ``ray_address``; ``workers`` only where it applied (local, or a Ray instance started here
        with that many CPUs: a joined cluster's CPUs are its own); for Ray ``cluster`` (joined / started /
        existing), ``nodes``, ``cluster_cpus`` and ``startup_s``."""
        rec: dict[str, Any] = {"backend": self.backend, "ray_address": self.address}
        if self.backend != "ray" or self.cluster == "started":
            rec["workers"] = workers
        if self.backend == "ray":
            rec.update(cluster=self.cluster, nodes=self.nodes, cluster_cpus=self.cluster_cpus,
                       startup_s=round(self.startup_s, 3))
        return rec
