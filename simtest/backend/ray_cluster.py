"""Units of work on a Ray cluster: joining (or starting) Ray and checking it before any write, one clear line for
every failed join, retries of units whose worker or node was lost, Ray's own logs kept out of the terminal
(imported only for ``--backend ray``)."""

from __future__ import annotations

import hashlib
import os
import pickle
import sys
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from simtest.backend.contract import Backend, BackendError, RunStats, UnitFailure

# --- Ray -------------------------------------------------------------------------------------------------
#: Initialisers already run in this (worker) process, by key.
_INITIALISED: set[str] = set()

#: Seconds a join may take before it is given up ($SIMTEST_RAY_CONNECT_TIMEOUT overrides): a head answers in
#: about one; Ray itself would retry for 20 s (a port that is not a head) or minutes (one that never answers).
CONNECT_TIMEOUT_S = 8.0

#: Seconds the nodes of a joined cluster get to report their simtest version (a busy node is skipped).
VERSION_CHECK_TIMEOUT_S = 30.0

#: Environment passed on to the workers (runtime_env), when set here.
_PASSED_ENV = ("MUJOCO_GL", "PYOPENGL_PLATFORM", "SIMTEST_CACHE", "LP_NUM_THREADS")


@dataclass
class _Connection:
    """The Ray instance this process uses: what it was made for, whether simtest made it (and shuts it down)."""

    key: tuple
    owned: bool
    cluster: str  # joined | started | existing
    address: str | None
    startup_s: float = 0.0
    nodes: int = 0
    cpus: int = 0

    def fill(self, stats: RunStats) -> None:
        stats.backend, stats.cluster, stats.address = "ray", self.cluster, self.address
        stats.startup_s, stats.nodes, stats.cluster_cpus = self.startup_s, self.nodes, self.cpus


_CONNECTION: _Connection | None = None
_OUR_ENV: dict[str, str] = {}  # environment set here for a local instance (removed when it stops)
_SESSIONS = 0  # open session() blocks: run_units inside one leaves the connection up


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


def _node_facts() -> dict[str, str]:
    """Run on each node of a joined cluster: the versions a unit's bytes depend on."""
    import platform

    import simtest

    return {"simtest": simtest.__version__, "python": platform.python_version()}


def _ray_module():
    try:
        import ray
    except ImportError as exc:
        raise BackendError("backend 'ray' needs the ray extra: pip install 'simtest[ray]'") from exc
    return ray


def _say(message: str) -> None:
    """One line on stderr through the progress bar's writer (a running bar is redrawn below it)."""
    try:
        from tqdm import tqdm

        tqdm.write(f"simtest: {message}", file=sys.stderr)
    except ImportError:  # pragma: no cover - tqdm is a dependency
        print(f"simtest: {message}", file=sys.stderr)


def _verbose_ray() -> bool:
    """Whether Ray's worker and raylet logs are streamed to this terminal: with ``-vv`` (simtest logging at
    DEBUG) only."""
    import logging

    return logging.getLogger("simtest").getEffectiveLevel() <= logging.DEBUG


def _init_kwargs() -> dict[str, Any]:
    env = {k: os.environ[k] for k in _PASSED_ENV if k in os.environ}
    return {"include_dashboard": False, "logging_level": "WARNING", "log_to_driver": _verbose_ray(),
            "runtime_env": {"env_vars": env} if env else None}


def connect(backend: Backend) -> _Connection:
    """The Ray instance for ``backend``: the one this process holds if it was made for the same settings, else
    a new one (joined at ``backend.address``, or started here with ``backend.workers`` CPUs), checked."""
    global _CONNECTION
    ray = _ray_module()
    key = (backend.address, None if backend.address else backend.workers)
    if _CONNECTION is not None:
        if ray.is_initialized() and _CONNECTION.key == key:
            return _CONNECTION
        release()  # shut down by its owner, or made for other settings (a command that failed early)
    if ray.is_initialized():  # the caller's own (a notebook, a test fixture): used as it is, left running
        if backend.address is not None:
            _check_reachable(backend.address)  # still: an address that cannot answer is a mistake
        _CONNECTION = _Connection(key, owned=False, cluster="existing", address=backend.address)
        _CONNECTION.nodes, _CONNECTION.cpus = _count(ray)
        return _CONNECTION
    t0 = time.perf_counter()
    if backend.address is None:
        _start_local(ray, backend.workers)
        conn = _Connection(key, owned=True, cluster="started", address=None)
    else:
        _join(ray, backend.address)
        conn = _Connection(key, owned=True, cluster="joined", address=backend.address)
    _CONNECTION = conn
    if not _verbose_ray():
        _condense_ray_errors()
    try:
        conn.nodes, conn.cpus = _count(ray)
        if conn.cpus < 1:
            raise BackendError(f"the Ray cluster at {backend.address} has {conn.nodes} alive node(s) but no CPUs: "
                               f"start its nodes with `ray start ... --num-cpus N` (N >= 1)")
        if conn.cluster == "joined":
            _check_versions(ray, backend.address)
    except BaseException:
        release()
        raise
    conn.startup_s = time.perf_counter() - t0
    return conn


def release() -> None:
    """Shut down the Ray connection this process holds, if simtest made it."""
    global _CONNECTION
    conn, _CONNECTION = _CONNECTION, None
    if conn is not None and conn.owned:
        ray = _ray_module()
        if ray.is_initialized():
            ray.shutdown()
    if _OUR_ENV:
        for k, v in list(_OUR_ENV.items()):  # the auth settings of a local instance end with it
            if os.environ.get(k) == v:
                del os.environ[k]
            del _OUR_ENV[k]
        # ... in Ray's core too, which read them when the instance started: a later ray.init() of the user's
        # in this process would otherwise still ask for token authentication, without the token
        _refresh_ray_config()


def _condense_ray_errors() -> None:
    """Ray prints the errors its raylets publish (a dead raylet's message carries the last 20 lines of its
    log, a worker's death a paragraph) on this terminal even with ``log_to_driver=False``. Without ``-vv`` each
    becomes one line through the progress bar's writer naming a log file that keeps the full text."""
    try:
        import ray._private.worker as ray_worker
    except ImportError:  # pragma: no cover
        return
    original = getattr(ray_worker, "print_to_stdstream", None)
    if original is None or getattr(original, "simtest_condensed", False):
        return
    import tempfile

    log = Path(tempfile.gettempdir()) / f"simtest-ray-{os.getpid()}.log"
    last: list[str] = [""]

    def condensed(data, *args, **kwargs):
        if not isinstance(data, dict) or data.get("pid") != "raylet":
            return original(data, *args, **kwargs)
        lines = [line for m in data.get("lines", []) for line in str(m).splitlines()]
        try:
            with open(log, "a") as f:
                f.write("\n".join(lines) + "\n")
        except OSError:
            pass
        head = lines[0].split(" Possible reasons")[0].strip() if lines else ""
        if head and head != last[0]:
            last[0] = head
            _say(f"ray: {head} (Ray's message in full: {log})")
        return None

    condensed.simtest_condensed = True  # type: ignore[attr-defined]
    ray_worker.print_to_stdstream = condensed


def _count(ray) -> tuple[int, int]:
    nodes = sum(1 for n in ray.nodes() if n.get("Alive"))
    return nodes, int(ray.cluster_resources().get("CPU", 0))


def _start_local(ray, workers: int) -> None:
    """A new local Ray instance with ``workers`` CPUs (never one found in RAY_ADDRESS or /tmp/ray).

    Ray (2.5x on) turns token authentication on for a local ``ray.init()`` and, when there is no token yet,
    writes one to ``~/.ray/auth_token``; every later ``ray start --head`` on the machine then finds that file
    and requires the token from its drivers. To leave that alone, an instance started here gets a token of its
    own in this process's environment (``RAY_AUTH_MODE=token``, ``RAY_AUTH_TOKEN``: inherited by its raylet
    and workers, removed when it stops), unless the user chose a mode (``RAY_AUTH_MODE``) or a token
    (``RAY_AUTH_TOKEN``, ``RAY_AUTH_TOKEN_PATH``, the file, which is then used)."""
    import secrets

    if "RAY_AUTH_MODE" not in os.environ:  # Ray's default for a local instance, said (it warns otherwise)
        _OUR_ENV["RAY_AUTH_MODE"] = "token"
        if not any(k in os.environ for k in ("RAY_AUTH_TOKEN", "RAY_AUTH_TOKEN_PATH")) and \
                not (Path.home() / ".ray" / "auth_token").exists():
            _OUR_ENV["RAY_AUTH_TOKEN"] = secrets.token_hex(32)
        os.environ.update(_OUR_ENV)
        _refresh_ray_config()
    try:
        ray.init(address="local", num_cpus=workers, **_init_kwargs())
    except Exception as exc:  # any failure to start means the same to the user
        raise BackendError(f"cannot start a local Ray instance: {type(exc).__name__}: {_first_line(exc)}") from exc


def _refresh_ray_config() -> None:
    """Make this process's Ray core see auth settings changed in ``os.environ`` (what Ray itself does when it
    turns token authentication on)."""
    try:
        from ray._raylet import AuthenticationTokenLoader, Config

        Config.initialize("")
        AuthenticationTokenLoader.instance().reset_cache()
    except (ImportError, AttributeError):  # pragma: no cover - another Ray version
        pass


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip()
    return text.splitlines()[0] if text else type(exc).__name__


#: Run in a child process by :func:`_join`: connect, count, print one JSON line. Ray's own log lines (the
#: C++ core's retries) go to the child's stderr, which is a log file.
_PROBE = r"""
import json, sys
try:
    import ray
    ray.init(address=sys.argv[1], include_dashboard=False, logging_level="ERROR", log_to_driver=False)
    nodes = [n for n in ray.nodes() if n.get("Alive")]
    out = {"ok": True, "nodes": len(nodes), "cpus": ray.cluster_resources().get("CPU", 0), "ray": ray.__version__}
    ray.shutdown()
except BaseException as exc:
    out = {"ok": False, "error": type(exc).__name__ + ": " + (str(exc).strip().splitlines() or [""])[0]}
print("SIMTEST-PROBE " + json.dumps(out), flush=True)
"""


def _join(ray, address: str) -> None:
    """Join the cluster at ``address`` in this process, after a child process showed that it can (within
    :data:`CONNECT_TIMEOUT_S`, its Ray log lines kept in a file).

    Raises:
        BackendError: One line: the address, what answered there, the fix, and the log file.
    """
    import subprocess
    import tempfile

    if address.startswith("ray://"):
        from ray._private.utils import get_ray_client_dependency_error

        if get_ray_client_dependency_error() is not None:
            raise BackendError(f"cannot join Ray at {address}: ray:// addresses need Ray Client, which is not "
                               f"installed: pip install 'ray[client]=={ray.__version__}' (or pass the head's "
                               f"GCS address HOST:PORT without ray://, e.g. HOST:6379)")
    _check_reachable(address)
    if "RAY_AUTH_MODE" not in os.environ and any(k in os.environ for k in ("RAY_AUTH_TOKEN", "RAY_AUTH_TOKEN_PATH")):
        os.environ["RAY_AUTH_MODE"] = "token"  # a token given for the cluster: use it (Ray wants both)
        _refresh_ray_config()
    timeout = float(os.environ.get("SIMTEST_RAY_CONNECT_TIMEOUT", CONNECT_TIMEOUT_S))
    env = {**os.environ}
    env.setdefault("RAY_gcs_server_port_wait_time_s", str(max(1, int(timeout // 3))))  # Ray's retries: 20 s
    log = Path(tempfile.gettempdir()) / f"simtest-ray-join-{os.getpid()}.log"
    t0 = time.perf_counter()
    with open(log, "w") as err:
        proc = subprocess.Popen([sys.executable, "-c", _PROBE, address], stdout=subprocess.PIPE, stderr=err,
                                stdin=subprocess.DEVNULL, env=env, text=True, start_new_session=True)
        try:
            out, _ = proc.communicate(timeout=timeout)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.communicate()
            out = None
    seconds = time.perf_counter() - t0
    result: dict[str, Any] = {}
    for line in (out or "").splitlines():
        if line.startswith("SIMTEST-PROBE "):
            import json

            result = json.loads(line.split(" ", 1)[1])
    if not result.get("ok"):
        raise BackendError(_join_failure(address, out is None, result.get("error", ""), log, seconds))
    # it answered the child a moment ago; Ray's retries stay short and its C++ lines in the log all the same
    try:
        with _stderr_to(log), _env(RAY_gcs_server_port_wait_time_s=env["RAY_gcs_server_port_wait_time_s"]):
            ray.init(address=address, **_init_kwargs())
    except Exception as exc:
        raise BackendError(_join_failure(address, False, f"{type(exc).__name__}: {_first_line(exc)}", log,
                                         time.perf_counter() - t0)) from exc
    log.unlink(missing_ok=True)


@contextmanager
def _stderr_to(path: Path) -> Iterator[None]:
    """File descriptor 2 (where Ray's C++ core logs) appended to ``path`` for the block."""
    sys.stderr.flush()
    saved = os.dup(2)
    try:
        with open(path, "a") as f:
            os.dup2(f.fileno(), 2)
        yield
    finally:
        sys.stderr.flush()
        os.dup2(saved, 2)
        os.close(saved)


@contextmanager
def _env(**values: str) -> Iterator[None]:
    """Environment variables set for the block only (those set by the user are kept)."""
    added = {k: v for k, v in values.items() if k not in os.environ}
    os.environ.update(added)
    try:
        yield
    finally:
        for k in added:
            os.environ.pop(k, None)


def _join_failure(address: str, timed_out: bool, error: str, log: Path, seconds: float) -> str:
    """The one line that says why ``address`` could not be joined and what to do."""
    text = log.read_text(errors="replace") if log.is_file() else ""
    where = f"cannot join Ray at {address}"
    see = f"(Ray's log: {log})"
    if "InvalidAuthToken" in text or "Unauthenticated" in text or "AuthenticationError" in error:
        given = "a token that the head refuses" if os.environ.get("RAY_AUTH_MODE", "").lower() == "token" \
            else "no token"
        return (f"{where}: the head answered but refused this driver, which has {given} (token authentication "
                f"is on there): on the head node run `ray get-auth-token`, then here `export RAY_AUTH_MODE=token "
                f"RAY_AUTH_TOKEN=<that token>` (or RAY_AUTH_TOKEN_PATH=<a file holding it>) {see}")
    if "rpc_code: 12" in text or "UNIMPLEMENTED" in text.upper():
        return (f"{where}: a Ray process answered there that is not the head's GCS (a raylet's or worker's "
                f"port?): pass the port given to `ray start --head --port` (6379 by default; `ray status` on "
                f"the head prints the address) {see}")
    if timed_out:
        return (f"{where}: the port accepts connections but nothing answered as a Ray head within {seconds:.0f} s "
                f"(not a Ray GCS port, or a head too busy; $SIMTEST_RAY_CONNECT_TIMEOUT waits longer): pass the "
                f"port given to `ray start --head --port` {see}")
    if "Could not find any running Ray instance" in error:
        return (f"{where}: no Ray cluster runs on this machine: start one with `ray start --head`, or pass "
                f"HOST:PORT of a running head {see}")
    return f"{where}: {error or 'the connection failed'} {see}"


def _check_versions(ray, address: str | None) -> None:
    """Every alive node runs the driver's simtest and Python (a node that does not answer within
    :data:`VERSION_CHECK_TIMEOUT_S` is skipped with a warning).

    Raises:
        BackendError: A node that cannot import simtest or runs another version.
    """
    import platform

    from ray.exceptions import RayTaskError
    from ray.util.scheduling_strategies import NodeAffinitySchedulingStrategy

    import simtest

    task = ray.remote(num_cpus=0, max_retries=0)(_node_facts)
    refs = {}
    for node in ray.nodes():
        if node.get("Alive"):
            strategy = NodeAffinitySchedulingStrategy(node["NodeID"], soft=False)
            refs[task.options(scheduling_strategy=strategy).remote()] = \
                f"{node.get('NodeManagerAddress')}:{node.get('NodeManagerPort')}"
    ready, late = ray.wait(list(refs), num_returns=len(refs), timeout=VERSION_CHECK_TIMEOUT_S)
    mine = {"simtest": simtest.__version__, "python": platform.python_version()}
    wrong = []
    for ref in ready:
        try:
            facts = ray.get(ref)
        except RayTaskError as exc:
            wrong.append(f"{refs[ref]} cannot run simtest ({_first_line(getattr(exc, 'cause', None) or exc)})")
            continue
        except Exception as exc:  # noqa: BLE001 - the node went away meanwhile: the run's retries deal with it
            _log_debug(f"node {refs[ref]} did not report its versions: {exc}")
            continue
        minor = facts["python"].rsplit(".", 1)[0] != mine["python"].rsplit(".", 1)[0]
        if facts["simtest"] != mine["simtest"] or minor:
            wrong.append(f"{refs[ref]} runs simtest {facts['simtest']} on Python {facts['python']}")
    for ref in late:
        ray.cancel(ref, force=True)
    if late:
        _say(f"ray: {len(late)} node(s) of {address} did not report their simtest version within "
             f"{VERSION_CHECK_TIMEOUT_S:.0f} s: {', '.join(refs[r] for r in late)}")
    if wrong:
        raise BackendError(f"cannot use Ray at {address}: {'; '.join(wrong)} (this driver: simtest "
                           f"{mine['simtest']} on Python {mine['python']}): install the same simtest and Python "
                           f"on every node")


def _log_debug(message: str) -> None:
    import logging

    logging.getLogger(__name__).debug(message)


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
        raise BackendError(f"cannot join Ray at {address}: nothing accepts connections there ({exc}): start a "
                           f"head with `ray start --head --port PORT` on that machine, or pass --ray-address "
                           f"auto on a cluster node") from exc


def _lost(exc: BaseException) -> str:
    """What a lost unit lost: its node or its worker."""
    name = type(exc).__name__
    return "node" if "Node" in name or "node" in str(exc).lower().split("\n", 1)[0] else "worker"


def run_ray(fn, units: list, backend: Backend, init, init_args: tuple, stats: RunStats) -> Iterator[Any]:
    ray = _ray_module()
    connect(backend).fill(stats)
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
                    _say(f"{backend.name}: unit {units[i]!r} lost its {_lost(exc)} ({type(exc).__name__}); "
                         f"retry {attempts[i]}/{backend.retries}")
                    pending.append(i)
                else:
                    stats.failures.append(UnitFailure(units[i], f"{type(exc).__name__}: {_first_line(exc)}"))
                continue
            stats.finished += 1
            yield result
    finally:
        _cancel(ray, list(running))
        if _SESSIONS == 0:
            release()


#: Seconds the units in flight get to finish when a run stops early, before the rest are cancelled.
CANCEL_GRACE_S = 1.0


def _cancel(ray, refs: list) -> None:
    """Free the cluster's CPUs of a run that stopped early (an error, --fail-fast, Ctrl-C): cancel the units still
    in flight. Units finishing at that moment are left to finish (up to :data:`CANCEL_GRACE_S`): a cancel that
    meets a task's completion can abort the whole driver inside Ray's task manager ("Tried to complete task
    that was not pending", ray-project/ray#54846), which no Python code can catch. Best effort: Ray may still
    run a task whose worker was being started."""
    if not refs:
        return
    try:
        _, refs = ray.wait(refs, num_returns=len(refs), timeout=CANCEL_GRACE_S)
    except Exception:  # noqa: BLE001 - the cluster is going away: cancel what is listed
        pass
    for ref in refs:
        try:
            ray.cancel(ref, force=True)
        except Exception:  # noqa: BLE001 - already finished or gone: nothing to cancel
            pass


@contextmanager
def ray_session(backend: Backend, stats: RunStats | None = None) -> Iterator[None]:
    """:func:`simtest.backend.session` on Ray: one connection across the block's :func:`run_ray` calls."""
    global _SESSIONS
    conn = connect(backend)
    if stats is not None:
        conn.fill(stats)
    _SESSIONS += 1
    try:
        yield
    finally:
        _SESSIONS -= 1
        if _SESSIONS == 0:
            release()
