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
    assert not (site / "results").exists(), "docs/results is left out of the site"
    for guide in (ROOT / "docs" / "guides").glob("*.md"):
        assert (site / "guides" / guide.stem / "index.html").is_file(), guide.name
