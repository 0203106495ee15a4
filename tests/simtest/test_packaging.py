"""Every Python package of the source tree is listed in pyproject.toml (a plain `pip install .` ships it)."""

from __future__ import annotations

from pathlib import Path

ROOT = Path(__file__).parents[2]
MAPPED = {"objects": "simtest.objects", "generators": "simtest.generators", "envs": "simtest.envs"}
#: Folders of package data only (no __init__.py), listed as packages so that setuptools ships them.
DATA_PACKAGES = {"simtest.estimators.weights"}


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
    assert found | DATA_PACKAGES == listed


def test_the_wheel_holds_the_code_and_the_shipped_networks_and_builds_without_warnings(tmp_path):
    """A real wheel build (setuptools, no isolation: the venv's setuptools): every source module of the packages,
    the shipped checkpoint and its ONNX file, the dist-info, nothing else; no packaging warning."""
    import subprocess
    import sys
    import zipfile

    proc = subprocess.run([sys.executable, "-m", "pip", "wheel", str(ROOT), "--no-deps", "--no-build-isolation",
                           "-w", str(tmp_path)], capture_output=True, text=True, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr[-2000:]
    text = proc.stdout + proc.stderr
    assert "BuildBackendWarning" not in text and "SetuptoolsDeprecationWarning" not in text, text[-3000:]
    (wheel,) = tmp_path.glob("simtest-*.whl")
    names = set(zipfile.ZipFile(wheel).namelist())
    expected = set()
    for top, pkg in (("simtest", "simtest"), *MAPPED.items()):
        for path in (ROOT / top).rglob("*.py"):
            rel = path.relative_to(ROOT / top)
            if top == "simtest" and rel.parts[0] in MAPPED:
                continue
            expected.add("/".join([*pkg.split("."), *rel.parts]))
    weights = {f"simtest/estimators/weights/{p.name}" for p in (ROOT / "simtest" / "estimators" / "weights").iterdir()
               if p.suffix in (".pt", ".onnx")}
    assert any(w.endswith(".onnx") for w in weights) and any(w.endswith(".pt") for w in weights)
    code = {n for n in names if ".dist-info/" not in n}
    assert code == expected | weights, (sorted(code - expected - weights), sorted((expected | weights) - code))


def _pyproject_mujoco_floor() -> str:
    try:
        import tomllib
    except ModuleNotFoundError:  # Python 3.10
        import tomli as tomllib
    deps = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["dependencies"]
    spec = [d for d in deps if d.replace(" ", "").startswith("mujoco>=")]
    assert len(spec) == 1, f"pyproject.toml must declare mujoco>=X once, got {deps}"
    return spec[0].replace(" ", "").split(">=", 1)[1].split(",")[0]


def test_mujoco_floor_agrees_with_pyproject_and_the_installed_version():
    from importlib import metadata

    import mujoco

    import simtest
    from simtest.render.gl import version_tuple

    assert _pyproject_mujoco_floor() == simtest.MIN_MUJOCO
    assert version_tuple(mujoco.__version__) >= version_tuple(simtest.MIN_MUJOCO)
    assert metadata.version("mujoco") == mujoco.__version__
    # what the floor stands for: joint damping as a vector (set on the Panda's finger joints)
    joint = mujoco.MjSpec().worldbody.add_body().add_joint()
    joint.damping = [200.0, 0.0, 0.0]
    assert float(joint.damping[0]) == 200.0


def test_older_mujoco_is_refused_with_versions_and_the_upgrade_command():
    import pytest

    from simtest.render.gl import check_mujoco

    check_mujoco("3.7", installed="3.7.0")
    check_mujoco("3.7", installed="4.0.0")
    check_mujoco("3.7", installed="3.10.1")
    for old in ("3.6.0", "3.2.7", "2.3.7"):
        with pytest.raises(ImportError, match=rf"mujoco >= 3\.7, but mujoco {old} is installed.*pip install -U mujoco"):
            check_mujoco("3.7", installed=old)


def test_import_simtest_checks_the_installed_mujoco(tmp_path):
    """``import simtest`` reads the installed mujoco version from its distribution metadata: with an older
    mujoco first on the path it stops with the clear message (here a 3.6.0 distribution record)."""
    import os
    import subprocess
    import sys

    dist = tmp_path / "mujoco-3.6.0.dist-info"
    dist.mkdir()
    (dist / "METADATA").write_text("Metadata-Version: 2.1\nName: mujoco\nVersion: 3.6.0\n")
    env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(tmp_path), os.environ.get("PYTHONPATH", "")]))
    proc = subprocess.run([sys.executable, "-c", "import simtest"], env=env, capture_output=True, text=True)
    assert proc.returncode != 0
    assert "ImportError: simtest needs mujoco >= 3.7, but mujoco 3.6.0 is installed" in proc.stderr
    assert "pip install -U mujoco" in proc.stderr
    ok = subprocess.run([sys.executable, "-c", "import simtest"], capture_output=True, text=True)
    assert ok.returncode == 0, ok.stderr


def test_old_module_names_still_import_as_the_moved_modules():
    """Every module of the flat layout imports under its old name as the same module object, with a
    DeprecationWarning naming the new place."""
    import importlib
    import sys
    import warnings

    import simtest

    for old, new in simtest.MOVED_MODULES.items():
        sys.modules.pop(old, None)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            module = importlib.import_module(old)
        assert module is importlib.import_module(new), old
        assert any(issubclass(w.category, DeprecationWarning) and new in str(w.message) for w in caught), old
    from simtest.render import Renderer
    from simtest.render.rasterizer import Renderer as R2

    assert Renderer is R2
