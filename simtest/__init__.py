"""simtest: simulation-driven synthetic data and closed-loop grasp testbed for 6D pose estimation.

Conventions (see docs/architecture.md): metres, radians and seconds inside the library; millimetres only
inside :mod:`simtest.io.bop`. ``T_a_b`` maps points from frame ``b`` into frame ``a``. Camera frames follow
OpenCV (x right, y down, z forward); depth images hold planar z in metres, 0 meaning "no measurement".
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.util
import sys
import warnings

from simtest.render import gl as _gl

#: Oldest MuJoCo release simtest runs on (3.7 made joint damping a vector, which the Panda model sets).
#: pyproject.toml declares the same floor.
MIN_MUJOCO = "3.7"

_gl.configure()  # must precede any import of mujoco
_gl.check_mujoco(MIN_MUJOCO)

__version__ = "0.1.0"

__all__ = ["__version__", "MIN_MUJOCO", "MOVED_MODULES", "generate", "evaluate", "grasp", "sweep", "load_objects"]

#: The Python front door (:mod:`simtest.api`), loaded on first use so ``import simtest`` stays light.
_API = ("generate", "evaluate", "grasp", "sweep", "load_objects")


def __getattr__(name: str):
    if name in _API:
        from simtest import api

        return getattr(api, name)
    raise AttributeError(f"module 'simtest' has no attribute {name!r}")

#: Modules of the flat layout (before the packages render/, evaluation/, sweeps/ and data/) and of the trainers
#: (before the package training/), and where they live now. Importing an old name gives the new module (the same
#: object) with a DeprecationWarning.
MOVED_MODULES = {
    "simtest.gl": "simtest.render.gl", "simtest.render_pbr": "simtest.render.pbr",
    "simtest.raster": "simtest.render.zbuffer", "simtest.colour": "simtest.render.colour",
    "simtest.eval": "simtest.evaluation.run", "simtest.eval_images": "simtest.evaluation.images",
    "simtest.eval_tracking": "simtest.evaluation.tracking", "simtest.scoring": "simtest.evaluation.scoring",
    "simtest.tables": "simtest.evaluation.tables", "simtest.sweep": "simtest.sweeps.grid",
    "simtest.cells": "simtest.sweeps.cells", "simtest.report": "simtest.sweeps.report",
    "simtest.mixing": "simtest.data.mixing", "simtest.pointcloud_stream": "simtest.data.pointclouds",
    "simtest.estimators.training": "simtest.training",
    "simtest.estimators.keypoints.train": "simtest.training.keypoints",
    "simtest.estimators.segicp.train": "simtest.training.segmentation",
}


class _MovedModule(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds the old names of :data:`MOVED_MODULES` and hands back the module at its new place."""

    def find_spec(self, name, path=None, target=None):  # noqa: D102 - importlib protocol
        return importlib.util.spec_from_loader(name, self) if name in MOVED_MODULES else None

    def create_module(self, spec):  # noqa: D102
        new = MOVED_MODULES[spec.name]
        warnings.warn(f"{spec.name} moved to {new}; import it from there", DeprecationWarning, stacklevel=2)
        return importlib.import_module(new)

    def exec_module(self, module) -> None:  # noqa: D102 - the new module is already executed
        pass


sys.meta_path.append(_MovedModule())
