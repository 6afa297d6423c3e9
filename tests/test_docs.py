"""The documentation site (mkdocs.yml, docs/, tools/docs_hooks.py) builds with warnings as errors, and its
generated pages follow the code: the command-line reference from the argument parsers, the API reference from
the package as it is."""
from __future__ import annotations

import importlib.util
import os
import pathlib
import re
import subprocess
import sys

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]


def hooks():
    spec = importlib.util.spec_from_file_location("docs_hooks", ROOT / "tools" / "docs_hooks.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_api_reference_walks_the_package():
    """Every module of the package has a page, found on disk at build time; the study code, the command modules
    and private modules have none."""
    names = [name for name, _ in hooks().package_modules()]
    on_disk = {".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")
               for path in (ROOT / "stdm_drake").rglob("*.py")}
    assert names and len(names) == len(set(names))
    assert "stdm_drake" in names and "stdm_drake.cli" in names and set(names) <= on_disk
    assert not [name for name in names if re.search(r"\.(experiments|commands|_data)(\.|$)", name)]
    assert not [name for name in names if name.rsplit(".", 1)[-1].startswith("_")]
    public = {name for name in on_disk if not re.search(r"\.(experiments|commands|_data)(\.|$)", name)
              and not name.rsplit(".", 1)[-1].startswith("_")}
    assert set(names) == public


@pytest.mark.slow
def test_site_builds_strict(tmp_path):
    """`mkdocs build --strict` passes without one warning, and the generated pages are there."""
    site = tmp_path / "site"
    env = dict(os.environ, DRAKE_ALLOW_NETWORK="meshcat", NO_MKDOCS_2_WARNING="1")
    result = subprocess.run([sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(ROOT / "mkdocs.yml"),
                             "-d", str(site)], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    output = result.stdout + result.stderr
    assert result.returncode == 0, output[-4000:]
    warnings = [line for line in output.splitlines() if re.match(r"^\s*(WARNING|ERROR)\b", line)]
    assert not warnings, warnings
    from stdm_drake.cli import COMMANDS
    cli = (site / "reference" / "cli" / "index.html").read_text(encoding="utf-8")
    for name in COMMANDS:
        assert f'id="{name}"' in cli and f"stdm-drake {name}" in cli
    assert "--export-plans" in cli and "--tune" in cli       # options come from the parsers themselves
    api = site / "reference" / "api"
    for name, _ in hooks().package_modules():
        assert (api / name / "index.html").is_file(), name
    assert "LearnedDynamicsSystem" in (api / "stdm_drake.closed_loop.learned_system" / "index.html").read_text()
    assert not list(api.glob("stdm_drake.experiments*")) and not list(api.glob("stdm_drake.commands*"))
    assert (site / "benchmarks" / "index.html").is_file()
    shown = sorted(path.relative_to(site).as_posix() for path in (site / "results").rglob("*") if path.is_file())
    figures = sorted(path.relative_to(ROOT / "docs").as_posix() for path in (ROOT / "docs" / "results").rglob("*")
                     if path.suffix.lower() in hooks().FIGURE_SUFFIXES)
    assert figures and shown == figures, "the figures of docs/results are on the site, the rest of it is not"
    assert '<img alt="Run 2\'s closed loop' in (site / "reality_gap" / "index.html").read_text(encoding="utf-8")
    assert "pre-wrap" in (site / "stylesheets" / "extra.css").read_text() and "extra.css" in cli   # long commands wrap
    robot = re.search(r'id="robot".*?(?=<h2)', cli, re.S).group(0)     # nested subcommands listed
    assert 'id="robot-init"' in robot and 'id="robot-check"' in robot and "--srdf" in robot
    for guide in (ROOT / "docs" / "guides").glob("*.md"):
        assert (site / "guides" / guide.stem / "index.html").is_file(), guide.name


def test_every_figure_a_page_shows_is_committed():
    """An image a page or guide shows (`![...](path)`) names a committed file beside the page (the strict build
    also fails on it; this is the fast check)."""
    shown = 0
    for page in [*(ROOT / "docs").rglob("*.md"), ROOT / "README.md"]:
        if "results" in page.relative_to(ROOT).parts[1:]:
            continue
        for target in re.findall(r"!\[[^\]]*\]\(([^)\s]+)", page.read_text(encoding="utf-8")):
            if re.match(r"[a-z]+://", target):
                continue
            assert (page.parent / target).is_file(), f"{page.name} shows {target}, which is not there"
            shown += 1
    assert shown >= 2
