"""Calling an estimator safely: any fault of the estimator becomes a recorded failure, never the end of a run.

:func:`call_estimator` runs ``estimate(observation)`` once and turns every way it can go wrong into an
:class:`EstimatorFailure`:

* ``exception``: it raised an exception (the message keeps the exception type and text);
* ``exit``: it raised ``SystemExit`` (``sys.exit(...)``);
* ``timeout``: it did not return within the time limit (seconds);
* ``invalid-return``: it returned something other than a list or tuple (e.g. ``None``).

``KeyboardInterrupt`` is never caught: Ctrl-C stops the run.

:func:`check_estimate` checks one returned element (a :class:`PoseEstimate` or an object with ``obj_id``,
``R`` and ``t``; ``score`` and ``scale`` optional) and gives back a clean :class:`PoseEstimate` or an
:class:`InvalidEstimate` saying what was wrong and what is expected. The evaluation runner and the grasp
episode both use these two functions.

The time limit uses ``SIGALRM`` (``signal.setitimer(ITIMER_REAL)``), so it works in the main thread of a
process on POSIX systems; elsewhere the estimator runs without a limit and a warning is logged once. The
alarm interrupts Python code and sleeps; a single long call into native code (one huge NumPy operation, a
GPU kernel) is interrupted only when it returns to Python.
"""

from __future__ import annotations

import logging
import math
import operator
import signal
import threading
import time
import traceback
from dataclasses import dataclass
from typing import Any

import numpy as np

from simtest.errors import ConfigError
from simtest.estimators.base import Observation, PoseEstimate

__all__ = ["DEFAULT_TIMEOUT_S", "AUTO_TIMEOUT", "resolve_timeout", "FAILURE_KINDS", "EstimatorFailure",
           "InvalidEstimate", "call_estimator", "check_estimate", "check_timeout", "trace_tail", "TRACE_FRAMES",
           "log_fault"]

log = logging.getLogger(__name__)

#: Default time limit of one estimator call, seconds.
DEFAULT_TIMEOUT_S = 120.0
#: The time limit an evaluation takes when none is given: :data:`DEFAULT_TIMEOUT_S`, or the estimator's declared
#: ``time_limit_s`` where that is longer (:func:`resolve_timeout`).
AUTO_TIMEOUT = "auto"
#: Kinds of :class:`EstimatorFailure`.
FAILURE_KINDS = ("exception", "exit", "timeout", "invalid-return")
#: Largest deviation of ``R R^T`` from the identity accepted as a rotation.
ROTATION_TOL = 1e-3
#: Frames kept in :attr:`EstimatorFailure.trace_tail`.
TRACE_FRAMES = 3
_EXPECTED = "expected a list of PoseEstimate (obj_id, R 3x3 rotation, t (3,) in metres)"
_warned_no_timeout = False
#: Estimator faults logged by this process so far (:func:`log_fault`).
_faults_logged = 0


@dataclass(frozen=True)
class EstimatorFailure:
    """Why one estimator call produced no estimates.

    Attributes:
        kind: One of :data:`FAILURE_KINDS`.
        message: What happened, with the expected behaviour where that helps.
        exception_type: Name of the exception class (``""`` for ``invalid-return``).
        trace: The formatted traceback of an ``exception`` (for logs), else ``""``.
        trace_tail: The last frames (at most :data:`TRACE_FRAMES`) of the estimator's own code where it raised,
            exited or was stopped by the time limit, one line: ``file:line in function: source > ...``
            (outermost first); ``""`` when unknown.
    """

    kind: str
    message: str
    exception_type: str = ""
    trace: str = ""
    trace_tail: str = ""


@dataclass(frozen=True)
class InvalidEstimate:
    """Why one returned element is not a usable pose estimate.

    Attributes:
        problem: ``"type"`` (not PoseEstimate-like), ``"shape"`` (R not 3x3, t not 3, non-numeric),
            ``"non-finite"`` (NaN / inf in R, t, score or scale), ``"rotation"`` (R not a rotation) or
            ``"unknown-object"`` (obj_id not among the known objects).
        message: What was wrong and what is expected.
        obj_id: The element's object id when it has a valid one, else None.
    """

    problem: str
    message: str
    obj_id: int | None = None


class _EstimatorTimeout(BaseException):
    """Raised by the SIGALRM handler inside the estimator; a BaseException so ``except Exception`` in
    estimator code does not swallow it."""


def check_timeout(timeout: float | None) -> float | None:
    """The time limit in seconds, or None for no limit (``None`` or ``0``).

    Raises:
        ConfigError: A negative, non-finite or non-numeric value.
    """
    if timeout is None:
        return None
    if isinstance(timeout, bool) or not isinstance(timeout, (int, float)) or not math.isfinite(timeout) \
            or timeout < 0:
        raise ConfigError(f"timeout must be a number of seconds >= 0 (0 or None: no limit), got {timeout!r}")
    return float(timeout) if timeout > 0 else None


def resolve_timeout(timeout: float | str | None, estimator: Any = None) -> float | None:
    """The time limit of one call in seconds (None: no limit). ``timeout`` :data:`AUTO_TIMEOUT` gives
    :data:`DEFAULT_TIMEOUT_S`, raised to the estimator's ``time_limit_s`` (seconds one call may take, declared
    by estimators that take minutes per image) when it declares a longer one; numbers as :func:`check_timeout`.

    Raises:
        ConfigError: A bad ``timeout``, or a declared ``time_limit_s`` that is not a positive number (naming the
            estimator's type and the value).
    """
    if timeout != AUTO_TIMEOUT:
        return check_timeout(timeout)
    declared = getattr(estimator, "time_limit_s", None)
    if declared is None:
        return DEFAULT_TIMEOUT_S
    if isinstance(declared, bool) or not isinstance(declared, (int, float)) or not math.isfinite(declared) \
            or declared <= 0:
        raise ConfigError(f"{type(estimator).__name__}.time_limit_s must be a positive number of seconds, got "
                          f"{declared!r}")
    return max(DEFAULT_TIMEOUT_S, float(declared))


def _timeout_possible() -> bool:
    """SIGALRM timers work here (POSIX, main thread); warn once when they do not."""
    global _warned_no_timeout
    ok = hasattr(signal, "SIGALRM") and hasattr(signal, "setitimer") and \
        threading.current_thread() is threading.main_thread()
    if not ok and not _warned_no_timeout:
        _warned_no_timeout = True
        log.warning("estimator time limit unavailable here (needs SIGALRM in the main thread); estimators run "
                    "without a timeout")
    return ok


def _run_with_alarm(est: Any, observation: Observation, limit: float) -> Any:
    """``est.estimate(observation)`` with a SIGALRM after ``limit`` s; the previous handler and timer (its
    remaining time) are restored afterwards."""
    fired = False

    def on_alarm(signum: int, frame: Any) -> None:
        nonlocal fired
        fired = True
        raise _EstimatorTimeout()

    t0 = time.monotonic()
    old_handler = signal.signal(signal.SIGALRM, on_alarm)
    old_delay = 0.0
    try:
        old_delay, _ = signal.setitimer(signal.ITIMER_REAL, limit)
        try:
            out = est.estimate(observation)
        except (Exception, SystemExit):
            if fired:  # the estimator turned the timeout into an error of its own
                raise _EstimatorTimeout() from None
            raise
        finally:
            signal.setitimer(signal.ITIMER_REAL, 0)
        if fired:  # the estimator caught the timeout itself and returned late
            raise _EstimatorTimeout()
        return out
    finally:
        signal.signal(signal.SIGALRM, old_handler)
        if old_delay > 0:
            signal.setitimer(signal.ITIMER_REAL, max(old_delay - (time.monotonic() - t0), 1e-6))


def call_estimator(est: Any, observation: Observation,
                   timeout: float | None = DEFAULT_TIMEOUT_S) -> tuple[list, EstimatorFailure | None]:
    """Call ``est.estimate(observation)`` once, within ``timeout`` seconds.

    Args:
        est: An object with ``estimate(observation)``.
        observation: The image to estimate on.
        timeout: Time limit, seconds (``None`` or ``0``: none).

    Returns:
        ``(elements, None)`` with the returned elements (a list, not yet checked one by one: see
        :func:`check_estimate`), or ``([], failure)``. ``KeyboardInterrupt`` propagates.
    """
    limit = check_timeout(timeout)
    try:
        if limit is not None and _timeout_possible():
            out = _run_with_alarm(est, observation, limit)
        else:
            out = est.estimate(observation)
    except _EstimatorTimeout as exc:
        return [], EstimatorFailure("timeout", f"estimate() did not return within the {limit:g} s time limit",
                                    "TimeoutError", trace_tail=trace_tail(exc))
    except SystemExit as exc:
        return [], EstimatorFailure("exit", f"estimate() called sys.exit({exc.code!r}); estimators must return "
                                    "or raise, never exit", "SystemExit", traceback.format_exc(), trace_tail(exc))
    except Exception as exc:  # noqa: BLE001 - every estimator error is a recorded failure
        return [], EstimatorFailure("exception", f"{type(exc).__name__}: {exc}", type(exc).__name__,
                                    traceback.format_exc(), trace_tail(exc))
    if not isinstance(out, (list, tuple)):
        return [], EstimatorFailure("invalid-return", f"estimate() returned {_describe(out)}; {_EXPECTED}")
    return list(out), None


def trace_tail(exc: BaseException, frames: int = TRACE_FRAMES) -> str:
    """The last ``frames`` frames of ``exc``'s traceback outside this module, on one line:
    ``path:line in function: source > ...`` (outermost first)."""
    here = __file__
    summary = [f for f in traceback.extract_tb(exc.__traceback__) if f.filename != here]
    return " > ".join(f"{f.filename}:{f.lineno} in {f.name}: {(f.line or '').strip()}" for f in summary[-frames:])


def _describe(value: Any) -> str:
    if value is None:
        return "None"
    name, text = type(value).__name__, repr(value)
    return f"{'an' if name[0] in 'aeiou' else 'a'} {name} ({text[:60] + '...' if len(text) > 60 else text})"


def check_estimate(e: Any, known: set[int] | None = None,
                   index: int | None = None) -> tuple[PoseEstimate | None, InvalidEstimate | None]:
    """Check one returned element and convert it to a clean :class:`PoseEstimate`.

    Args:
        e: The element: a :class:`PoseEstimate` or any object with ``obj_id`` (int), ``R`` (3x3 rotation,
            model -> camera), ``t`` (3 values, metres) and optionally ``score`` and ``scale`` (finite).
        known: Object ids the estimate may refer to (None: any).
        index: Position of the element in the returned list (named in the message).

    Returns:
        ``(estimate, None)`` with float64 ``R`` (3, 3) and ``t`` (3,), or ``(None, why)``.
    """
    where = "estimate" if index is None else f"estimate [{index}]"
    if not all(hasattr(e, a) for a in ("obj_id", "R", "t")):
        return None, InvalidEstimate("type", f"{where} is {_describe(e)}; expected a PoseEstimate with obj_id, "
                                             "R (3x3) and t (3,) in metres")
    try:
        obj_id = operator.index(e.obj_id)
    except TypeError:
        return None, InvalidEstimate("type", f"{where}: obj_id must be an integer, got {_describe(e.obj_id)}")
    try:
        R = np.array(e.R, dtype=np.float64)
        t = np.array(e.t, dtype=np.float64)
        score = float(getattr(e, "score", 1.0))
        scale = float(getattr(e, "scale", 1.0))
    except (TypeError, ValueError) as exc:
        return None, InvalidEstimate("shape", f"{where}: R, t, score and scale must be numeric: {exc}", obj_id)
    if R.shape != (3, 3) or t.size != 3:
        return None, InvalidEstimate("shape", f"{where}: R must be 3x3 and t 3 values (metres), got shapes "
                                              f"{R.shape} and {t.shape}", obj_id)
    t = t.reshape(3)
    if not (np.isfinite(R).all() and np.isfinite(t).all() and math.isfinite(score) and math.isfinite(scale)):
        return None, InvalidEstimate("non-finite", f"{where}: non-finite estimate (NaN or inf in R, t, score or "
                                                   "scale); expected finite values", obj_id)
    dev = float(np.abs(R @ R.T - np.eye(3)).max())
    det = float(np.linalg.det(R))
    if dev > ROTATION_TOL or det < 0:
        return None, InvalidEstimate("rotation", f"{where}: R is not a rotation matrix (max |R R^T - I| = "
                                                 f"{dev:.2g}, det = {det:.3f}); expected R R^T = I, det = +1",
                                     obj_id)
    if known is not None and obj_id not in known:
        return None, InvalidEstimate("unknown-object", f"{where}: unknown obj_id {obj_id}; known objects: "
                                                       f"{sorted(known)}", obj_id)
    info = getattr(e, "info", None)
    return PoseEstimate(obj_id=obj_id, R=R, t=t, score=score, scale=scale,
                        target_index=getattr(e, "target_index", None),
                        info=dict(info) if isinstance(info, dict) else {}), None


def log_fault(logger: logging.Logger, where: str, fault: EstimatorFailure, record: str) -> None:
    """Log one estimator fault so that a run with thousands of them stays readable: the first of this process
    as a warning with its full traceback, every later one as a single line at INFO (shown with ``-v``). The
    command's summary counts them all and ``record`` (the file that holds every one) is named.

    Args:
        logger: The caller's logger. where: ``scene 3 image 12``, ``episode 7``. record: ``failures.csv``.
    """
    global _faults_logged
    _faults_logged += 1
    if _faults_logged == 1:
        logger.warning("estimator failed on %s (%s): %s%s\n(further failures: one line each with -v; all are in "
                       "%s)", where, fault.kind, fault.message, "\n" + fault.trace if fault.trace else "", record)
    else:
        logger.info("estimator failed on %s (%s): %s", where, fault.kind, " ".join(fault.message.split()))
