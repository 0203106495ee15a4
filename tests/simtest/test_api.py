"""The Python front door: the example of the Python API page (docs/api.md) runs as written (in a temporary
folder), and the facade hands bad input to the same checks as the command line."""

from __future__ import annotations

import os
import re
from pathlib import Path

import pytest

import simtest
from simtest.errors import ConfigError

API_PAGE = Path(__file__).resolve().parents[2] / "docs" / "api.md"


def _page_block(title: str) -> str:
    """The first ```python block after the heading ``title`` of docs/api.md."""
    text = API_PAGE.read_text(encoding="utf-8")
    section = text[text.index(title):]
    return re.search(r"```python\n(.*?)```", section, re.S).group(1)


def test_the_api_page_python_block_runs(tmp_path, capsys):
    code = _page_block("# Python API")
    here = os.getcwd()
    os.chdir(tmp_path)
    try:
        exec(compile(code, "docs/api.md", "exec"), {})
    finally:
        os.chdir(here)
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("2 ") and "frames/s" in out[0]
    assert re.fullmatch(r"ADD\(-S\)-0\.1d \d+\.\d % \[\d+\.\d, \d+\.\d\]", out[1])
    assert 0.0 <= float(out[2]) <= 1.0
    assert (tmp_path / "data" / "api-eval" / "metrics.json").is_file()


def test_the_facade_is_importable_and_checks_like_the_cli(tmp_path):
    assert set(simtest.__all__) >= {"generate", "evaluate", "grasp", "sweep", "load_objects"}
    from simtest.api import sweep

    with pytest.raises(ConfigError):
        simtest.generate(tmp_path / "x", scenes=0, progress=False)
    with pytest.raises(ConfigError):
        sweep({"no_such_key": 1}, tmp_path / "sweep")
    with pytest.raises(AttributeError, match="no attribute 'nothing'"):
        simtest.nothing  # noqa: B018
    from simtest.envs import PandaGraspEnv  # the env class from the package, as the docs write it

    assert PandaGraspEnv.__name__ == "PandaGraspEnv"
