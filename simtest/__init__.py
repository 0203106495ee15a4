"""simtest: simulation-driven synthetic data and closed-loop grasp testbed for 6D pose estimation.

Conventions (see docs/architecture.md): metres, radians and seconds inside the library; millimetres only
inside :mod:`simtest.io.bop`. ``T_a_b`` maps points from frame ``b`` into frame ``a``. Camera frames follow
OpenCV (x right, y down, z forward); depth images hold planar z in metres, 0 meaning "no measurement".
"""

from __future__ import annotations

from simtest import gl as _gl

#: Oldest MuJoCo release simtest runs on (3.7 made joint damping a vector, which the Panda model sets).
#: pyproject.toml declares the same floor.
MIN_MUJOCO = "3.7"

_gl.configure()  # must precede any import of mujoco
_gl.check_mujoco(MIN_MUJOCO)

__version__ = "0.1.0"

__all__ = ["__version__", "MIN_MUJOCO"]
