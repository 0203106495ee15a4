"""Rendering: every back end draws the same settled MuJoCo state; depth, masks and ground truth always come from
the exact rasterizer, so all profiles share them.

| module | owns |
|---|---|
| :mod:`~simtest.render.gl` | the headless GL backend (EGL, else OSMesa), chosen before MuJoCo is imported; fork and torch guards; the per-machine thread budget |
| :mod:`~simtest.render.rasterizer` | :class:`Renderer`: MuJoCo's rasterizer, one GL context per process, ``Frame(rgb, depth m, seg)``, fast / quality profiles |
| :mod:`~simtest.render.pbr` | :class:`~simtest.render.pbr.PbrRenderer`: the ``pbr`` profile's RGB, path-traced by Mitsuba 3 and denoised by OIDN (extra ``pbr``, lazy) |
| :mod:`~simtest.render.zbuffer` | a numpy z-buffer depth rasterizer of posed meshes (VSD, checks), no GL |
| :mod:`~simtest.render.colour` | the sRGB transfer function, both ways |

``from simtest.render import Renderer`` works; importing this package alone imports neither MuJoCo nor GL.
"""

from __future__ import annotations

import importlib
from typing import Any

__all__ = ["Renderer", "Frame", "Profile", "camera_id"]


def __getattr__(name: str) -> Any:
    """The rasterizer's public names, imported on first use (MuJoCo must not load before the GL choice)."""
    if name in __all__:
        return getattr(importlib.import_module("simtest.render.rasterizer"), name)
    raise AttributeError(f"module 'simtest.render' has no attribute {name!r}")
