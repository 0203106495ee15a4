"""Choose MuJoCo's headless OpenGL backend before MuJoCo is imported, check MuJoCo's version, and guard the
process-level GL hazards.

MuJoCo and PyOpenGL pick their GL platform once, at import time, from ``MUJOCO_GL`` / ``PYOPENGL_PLATFORM``.
:func:`configure` runs when ``simtest`` is imported: a value the user set is kept; otherwise EGL (Mesa or a
GPU driver) is chosen when ``libEGL`` is present, else OSMesa when ``libOSMesa`` is present.
:func:`check_mujoco` runs then too, reading the installed version from the package metadata (MuJoCo itself is
not imported).

Two hazards concern the whole process, so :mod:`simtest.render.rasterizer` calls :func:`before_first_context` before it
makes a GL context:

* **fork after GL**: GL contexts (and the driver threads and locks behind them) do not survive ``fork()``. A
  process forked after its parent made a context hangs in ``mjr_makeContext``; it raises a
  :class:`~simtest.errors.RenderError` instead (:func:`check_fork`), which says to start workers with the
  ``spawn`` method (``gymnasium.make_vec(..., vectorization_mode="async", vector_kwargs={"context": "spawn"})``).
* **torch's compiler stack after EGL**: with the CUDA wheels of torch from PyPI, importing ``torch._dynamo``
  (as stable-baselines3 does) after the first EGL render crashes the process (SIGSEGV); importing it before
  works. When torch is already imported, ``torch._dynamo`` is imported before the first context; call
  :func:`prepare_torch` (or set ``SIMTEST_PREPARE_TORCH=1``) to do so even if torch is imported later.
  ``import simtest`` itself never imports torch.
"""

from __future__ import annotations

import ctypes.util
import os
import re
import sys
from importlib import metadata

__all__ = ["configure", "backend", "check_mujoco", "version_tuple", "SYSTEM_PACKAGES_HINT", "prepare_torch",
           "check_fork", "before_first_context", "FORK_HINT", "forked_after_context", "context_made"]

#: The per-machine thread budget moved to :mod:`simtest.backend.threads`; these names forward there.
MOVED = ("ThreadBudget", "available_cores", "workers_per_machine", "thread_budget", "apply_thread_budget")


def __getattr__(name: str):
    """The moved names (:data:`MOVED`), from :mod:`simtest.backend.threads`, with a DeprecationWarning."""
    if name in MOVED:
        import warnings

        from simtest.backend import threads

        warnings.warn(f"simtest.render.gl.{name} moved to simtest.backend.threads.{name}", DeprecationWarning,
                      stacklevel=2)
        return getattr(threads, name)
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")

#: What to do instead of forking a process that has made a GL context.
FORK_HINT = (
    "start worker processes with the 'spawn' method instead: gymnasium.make_vec(..., vectorization_mode='async', "
    "vector_kwargs={'context': 'spawn'}) or multiprocessing.get_context('spawn')")

_STATE = {"context_made": False, "forked_after_context": False, "torch_prepared": False}

SYSTEM_PACKAGES_HINT = (
    "headless rendering needs EGL or OSMesa. On Debian/Ubuntu install "
    "'libegl1 libgl1 libegl-mesa0 libgl1-mesa-dri' (EGL, MUJOCO_GL=egl) or 'libosmesa6' (MUJOCO_GL=osmesa), "
    "and PyOpenGL >= 3.1.7"
)


def configure() -> str:
    """Set ``MUJOCO_GL`` and ``PYOPENGL_PLATFORM`` if unset; return the chosen backend name."""
    chosen = os.environ.get("MUJOCO_GL", "").strip().lower()
    if not chosen and "mujoco" not in sys.modules:
        if ctypes.util.find_library("EGL"):
            chosen = "egl"
        elif ctypes.util.find_library("OSMesa"):
            chosen = "osmesa"
        else:
            chosen = "egl"  # rendering will fail with SYSTEM_PACKAGES_HINT; physics-only use still works
        os.environ["MUJOCO_GL"] = chosen
    if chosen in ("egl", "osmesa"):
        os.environ.setdefault("PYOPENGL_PLATFORM", chosen)
    return chosen


def backend() -> str:
    """The backend MuJoCo was (or will be) configured with."""
    return os.environ.get("MUJOCO_GL", "")


def version_tuple(version: str) -> tuple[int, ...]:
    """The leading numeric release of a version string: ``"3.7.0rc1"`` -> ``(3, 7, 0)``; ``()`` if none."""
    m = re.match(r"\d+(?:\.\d+)*", version.strip())
    return tuple(int(p) for p in m.group(0).split(".")) if m else ()


def check_mujoco(required: str, installed: str | None = None) -> None:
    """Raise ``ImportError`` if the installed MuJoCo is older than ``required``.

    Args:
        required: The oldest supported release, e.g. ``"3.7"``.
        installed: The version to check; by default that of the installed ``mujoco`` distribution (nothing is
            checked when it is not installed: importing it will fail with its own error).
    """
    if installed is None:
        try:
            installed = metadata.version("mujoco")
        except metadata.PackageNotFoundError:
            return
    have, need = version_tuple(installed), version_tuple(required)
    n = max(len(have), len(need))
    if have + (0,) * (n - len(have)) < need + (0,) * (n - len(need)):
        raise ImportError(f"simtest needs mujoco >= {required}, but mujoco {installed} is installed; "
                          f"upgrade it with: pip install -U mujoco")


def _after_fork_in_child() -> None:
    if _STATE["context_made"]:
        _STATE["forked_after_context"] = True


if hasattr(os, "register_at_fork"):
    os.register_at_fork(after_in_child=_after_fork_in_child)


def forked_after_context() -> bool:
    """Whether this process was forked from one that had made a GL context (its GL state is unusable here)."""
    return _STATE["forked_after_context"]


def check_fork() -> None:
    """Raise :class:`~simtest.errors.RenderError` in a process forked after its parent made a GL context.

    Creating or using a context there would hang (``mjr_makeContext`` never returns).
    """
    if _STATE["forked_after_context"]:
        from simtest.errors import RenderError

        raise RenderError(f"this process was forked from one that had already made an OpenGL context "
                          f"(MUJOCO_GL={backend()!r}); GL contexts do not survive fork() and rendering here would "
                          f"hang. {FORK_HINT}")


def prepare_torch() -> bool:
    """Import torch's compiler stack (``torch._dynamo``) now, before any GL context exists.

    With the CUDA wheels of torch from PyPI, importing ``torch._dynamo`` (stable-baselines3 does) after the
    first EGL render crashes the process; imported first, both work. Call this before the first render when
    torch will be used later; ``SIMTEST_PREPARE_TORCH=1`` makes the renderer call it. Returns False if torch is
    not installed.
    """
    try:
        import torch._dynamo  # noqa: F401
    except ImportError:
        return False
    _STATE["torch_prepared"] = True
    return True


def before_first_context() -> None:
    """Run by :mod:`simtest.render.rasterizer` before it makes a GL context: :func:`check_fork`, then import
    ``torch._dynamo`` if torch is already imported (or ``SIMTEST_PREPARE_TORCH=1``)."""
    check_fork()
    if _STATE["torch_prepared"] or _STATE["context_made"]:  # after the first context it would be too late
        return
    if "torch" in sys.modules or os.environ.get("SIMTEST_PREPARE_TORCH", "").strip() == "1":
        try:
            prepare_torch()
        except Exception:  # a broken torch install must not break rendering; torch reports it when used
            _STATE["torch_prepared"] = True


def context_made() -> None:
    """Record that this process has made a GL context (see :func:`check_fork`)."""
    _STATE["context_made"] = True
