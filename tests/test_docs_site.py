"""The documentation: the MkDocs site builds with warnings as errors (every internal link and anchor resolves,
the API reference is made from the docstrings), a broken link does fail that build, and the README stays a
short front door whose links all land."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"
#: The README's length limit, in lines: the front door, everything else lives under docs/.
MAX_README_LINES = 250


def _mkdocs_build(project: Path, site: Path) -> subprocess.CompletedProcess:
    """``mkdocs build --strict`` of the project folder ``project`` into ``site``."""
    env = {**os.environ, "NO_MKDOCS_2_WARNING": "1"}
    return subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "--site-dir", str(site)],
                          cwd=project, env=env, capture_output=True, text=True, timeout=600)


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    """The site built from this checkout's mkdocs.yml and docs/."""
    out = tmp_path_factory.mktemp("site")
    run = _mkdocs_build(ROOT, out)
    assert run.returncode == 0, f"mkdocs build --strict failed:\n{run.stdout}\n{run.stderr}"
    return out


def test_the_site_builds_strict_with_the_api_reference(site):
    api = (site / "api" / "index.html").read_text(encoding="utf-8")
    for name in ("simtest.api.generate", "simtest.api.evaluate", "simtest.api.grasp", "simtest.api.sweep",
                 "simtest.envs.grasp_env.PandaGraspEnv", "simtest.envs.episode.run_episode",
                 "simtest.metrics.add", "simtest.estimators.base.PoseEstimate"):
        assert f'id="{name}"' in api, f"the API reference has no entry {name}"
    assert (site / "index.html").is_file() and (site / "sim2real" / "index.html").is_file()


def test_every_page_under_docs_is_in_the_nav():
    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text(encoding="utf-8"))

    def pages(node) -> set[str]:
        if isinstance(node, str):
            return {node}
        if isinstance(node, list):
            return set().union(*(pages(n) for n in node))
        return set().union(*(pages(v) for v in node.values()))

    listed = pages(config["nav"])
    on_disk = {p.relative_to(ROOT / "docs").as_posix() for p in (ROOT / "docs").rglob("*.md")}
    assert on_disk - listed == set(), "pages missing from mkdocs.yml's nav"
    assert listed - on_disk == set(), "nav entries without a page"


def test_a_broken_link_or_anchor_fails_the_strict_build(tmp_path):
    """The validation settings of mkdocs.yml turn bad links and anchors into warnings, so --strict fails."""
    config = yaml.safe_load((ROOT / "mkdocs.yml").read_text(encoding="utf-8"))
    for target in ("missing.md", "index.md#no-such-heading"):
        project = tmp_path / target.replace("#", "_")
        (project / "docs").mkdir(parents=True)
        (project / "docs" / "index.md").write_text(f"# Home\n\n## A heading\n\n[a link]({target})\n")
        (project / "mkdocs.yml").write_text(yaml.safe_dump({"site_name": "t", "validation": config["validation"]}))
        run = _mkdocs_build(project, tmp_path / "site")
        assert run.returncode != 0, f"a link to {target} built without an error"
        assert target.split("#")[-1] in run.stderr


def test_the_readme_is_a_short_front_door():
    lines = README.read_text(encoding="utf-8").splitlines()
    assert len(lines) <= MAX_README_LINES, f"README.md has {len(lines)} lines; at most {MAX_README_LINES}"
    text = "\n".join(lines)
    assert "make demo" in text and "make test" in text
    for image in re.findall(r"!\[[^\]]*\]\(([^)]+)\)", text):
        assert (ROOT / image).is_file(), f"README image {image} does not exist"


def test_the_readme_test_command_is_what_make_test_runs():
    makefile = (ROOT / "Makefile").read_text(encoding="utf-8")
    assert "$(PY) -m pytest -q tests" in makefile
    assert ".venv/bin/python -m pytest -q tests" in README.read_text(encoding="utf-8")
    assert "make test" in (ROOT / ".ci" / "run").read_text(encoding="utf-8")


def test_every_readme_link_into_the_repository_lands(site):
    text = README.read_text(encoding="utf-8")
    links = [t for t in re.findall(r"\]\(([^)]+)\)", text) if not re.match(r"[a-z]+://", t)]
    assert links, "the README links to no page"
    for link in links:
        path, _, anchor = link.partition("#")
        assert (ROOT / path).exists(), f"README links to {path}, which does not exist"
        if anchor:
            assert path.startswith("docs/") and path.endswith(".md"), link
            page = site / Path(path).relative_to("docs").with_suffix("") / "index.html"
            assert f'id="{anchor}"' in page.read_text(encoding="utf-8"), f"README link {link}: no such anchor"
