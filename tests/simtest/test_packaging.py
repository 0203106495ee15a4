"""Every Python package of the source tree is listed in pyproject.toml (a plain `pip install .` ships it)."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).parents[2]
MAPPED = {"objects": "simtest.objects", "generators": "simtest.generators", "envs": "simtest.envs"}


def test_every_package_is_listed_in_pyproject():
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib
    listed = set(tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["packages"])
    found = set()
    for top in ("simtest", *MAPPED):
        for init in (ROOT / top).rglob("__init__.py"):
            parts = init.parent.relative_to(ROOT).parts
            name = ".".join((MAPPED[parts[0]].split(".") if parts[0] in MAPPED else [parts[0]]) + list(parts[1:]))
            found.add(name)
    assert found == listed
