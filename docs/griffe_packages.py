"""A griffe extension for the API reference (mkdocs.yml): simtest installs three top-level folders of the
repository as sub-packages (``envs/`` -> ``simtest.envs``, ``objects/`` -> ``simtest.objects``, ``generators/``
-> ``simtest.generators``; ``[tool.setuptools.package-dir]`` in pyproject.toml). griffe reads packages from
folders and would not find them under ``simtest``; this extension loads each folder and hangs it there."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import griffe

ROOT = Path(__file__).resolve().parents[1]
#: Sub-package name -> folder, as pyproject.toml maps them.
MAPPED = {"envs": ROOT / "envs", "objects": ROOT / "objects", "generators": ROOT / "generators"}


class MappedPackages(griffe.Extension):
    """Attach the mapped folders to the ``simtest`` package when griffe loads it."""

    def on_package(self, *, pkg: griffe.Module, loader: griffe.GriffeLoader, **kwargs: Any) -> None:
        if pkg.name != "simtest":
            return
        for name, folder in MAPPED.items():
            if name not in pkg.members:
                module = loader.load(folder, submodules=True)
                pkg.set_member(name, module)
