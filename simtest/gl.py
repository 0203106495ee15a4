"""Choose MuJoCo's headless OpenGL backend before MuJoCo is imported, and check MuJoCo's version.

MuJoCo and PyOpenGL pick their GL platform once, at import time, from ``MUJOCO_GL`` / ``PYOPENGL_PLATFORM``.
:func:`configure` runs when ``simtest`` is imported: a value the user set is kept; otherwise EGL (Mesa or a
GPU driver) is chosen when ``libEGL`` is present, else OSMesa when ``libOSMesa`` is present.
:func:`check_mujoco` runs then too, reading the installed version from the package metadata (MuJoCo itself is
not imported).
"""

from __future__ import annotations

import ctypes.util
import os
import re
import sys
from importlib import metadata

__all__ = ["configure", "backend", "check_mujoco", "version_tuple", "SYSTEM_PACKAGES_HINT"]

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
