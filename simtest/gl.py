"""Choose MuJoCo's headless OpenGL backend before MuJoCo is imported.

MuJoCo and PyOpenGL pick their GL platform once, at import time, from ``MUJOCO_GL`` / ``PYOPENGL_PLATFORM``.
:func:`configure` runs when ``simtest`` is imported: a value the user set is kept; otherwise EGL (Mesa or a
GPU driver) is chosen when ``libEGL`` is present, else OSMesa when ``libOSMesa`` is present.
"""

from __future__ import annotations

import ctypes.util
import os
import sys

__all__ = ["configure", "backend", "SYSTEM_PACKAGES_HINT"]

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
