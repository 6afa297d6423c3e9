"""MkDocs hooks of the documentation site (mkdocs.yml, `hooks:`): the pages that are generated at every build
from the code, so that they cannot drift from it.

- `reference/cli.md`: every `stdm-drake` subcommand's usage, description and options, rendered from the real
  argument parsers (`stdm_drake.cli.COMMANDS`, each module's `add_arguments`).
- `reference/api/*.md`: one page per module of the `stdm_drake` package, found by walking the package's folder
  at build time (subpackages `experiments`, `commands` and `_data` left out), each page one mkdocstrings
  directive; `reference/api/index.md` lists every module with its docstring's first line. The nav entry
  `reference/api/index.md` in mkdocs.yml is expanded into these pages.
- `benchmarks.md`: the repository's BENCHMARKS.md, which stays at the root.
- the figures under `docs/results/` (the rest of that folder stays out of the site).

Every page also loses its number-source comments (`<!-- = FILE: EXPR -->`, checked by
tools/check_doc_numbers.py) before it is rendered: they are for the check, and their expressions' brackets
would read as cross-references.
"""
from __future__ import annotations

import argparse
import ast
import html
import importlib
import os
import pathlib
import re

ROOT = pathlib.Path(__file__).resolve().parents[1]
PACKAGE = "stdm_drake"
SKIPPED = {"experiments", "commands", "_data"}   # subpackages the API reference leaves out
API_INDEX = "reference/api/index.md"
CLI_PAGE = "reference/cli.md"
USAGE_WIDTH = 100


# ---------------------------------------------------------------------------------------------------------- API

def package_modules(root: pathlib.Path = ROOT) -> list[tuple[str, pathlib.Path]]:
    """(dotted name, file) of every module and package of the package as its folder holds it now, in a stable
    order: a package (its __init__.py) before its modules; private modules and the SKIPPED subpackages left out."""
    base = root / PACKAGE
    found = []
    for path in sorted(base.rglob("*.py")):
        parts = path.relative_to(root).with_suffix("").parts
        if any(part in SKIPPED for part in parts[1:]) or "__pycache__" in parts:
            continue
        if any(part.startswith("_") for part in parts[1:-1]):
            continue
        if parts[-1] == "__init__":
            parts = parts[:-1]
        elif parts[-1].startswith("_"):
            continue
        if not all((root.joinpath(*parts[:i]) / "__init__.py").is_file() for i in range(1, len(parts))):
            continue   # (a folder that is no package)
        found.append((".".join(parts), path))
    return sorted(found, key=lambda item: item[0].split("."))


def summary_line(path: pathlib.Path) -> str:
    """The first sentence of a module's docstring (its first paragraph, cut at the first full stop), read
    without importing the module."""
    try:
        docstring = ast.get_docstring(ast.parse(path.read_text(encoding="utf-8"))) or ""
    except SyntaxError:
        return ""
    first = " ".join(docstring.strip().split("\n\n")[0].split())
    return re.split(r"(?<=\.)\s", first, maxsplit=1)[0]


def api_page_uri(name: str) -> str:
    return f"reference/api/{name}.md"


def api_page(name: str) -> str:
    return f"# `{name}`\n\n::: {name}\n"


def api_index(modules) -> str:
    lines = ["# API reference", "",
             "One page per module of the `stdm_drake` package, generated from the docstrings at every build "
             "(the package's folder is walked, so a module that moves or is renamed moves here too). The study "
             "code (`stdm_drake.experiments`) and the command modules (`stdm_drake.commands`, see the "
             "[command-line reference](../cli.md)) are left out.", "",
             "| module | what |", "|---|---|"]
    for name, path in modules:
        depth = name.count(".") - 1
        label = ("&nbsp;&nbsp;" * 2 * depth) + f"[`{name}`]({name}.md)"
        lines.append(f"| {label} | {escape(summary_line(path))} |")
    return "\n".join(lines) + "\n"


def api_nav(modules) -> list:
    """The nav entries of the API pages: the index, then each top-level module and each subpackage as a section
    holding the package page and its modules."""
    entries: list = [{"Overview": API_INDEX}]
    sections: dict[str, list] = {}
    for name, _ in modules:
        parts = name.split(".")
        if len(parts) == 1:
            entries.append({name: api_page_uri(name)})
            continue
        if len(parts) == 2 and not (ROOT / PACKAGE / parts[1]).is_dir():
            entries.append({name: api_page_uri(name)})
            continue
        sections.setdefault(".".join(parts[:2]), []).append({name: api_page_uri(name)})
    entries += [{section: pages} for section, pages in sections.items()]
    return entries


# ---------------------------------------------------------------------------------------------------------- CLI

def escape(text: str) -> str:
    """Text as Markdown that shows it as written: outside `code spans`, HTML and emphasis characters escaped;
    a table's bars everywhere."""
    def plain(part: str) -> str:
        return re.sub(r"([\\*_\[\]])", r"\\\1", html.escape(part, quote=False))
    parts = text.split("`")
    if len(parts) % 2 == 0:   # (an odd backtick would open a code span that never closes)
        parts = [text.replace("`", "'")]
    text = "`".join(plain(part) if index % 2 == 0 else part for index, part in enumerate(parts))
    return text.replace("|", "\\|")


def _formatter(prog):
    return argparse.HelpFormatter(prog, width=USAGE_WIDTH)


def _argument_row(action: argparse.Action) -> str:
    if action.option_strings:
        metavar = ""
        if action.nargs != 0:
            metavar = " " + _formatter("x")._format_args(action, action.metavar or action.dest.upper())
        names = ", ".join(f"`{option}{metavar}`" for option in action.option_strings)
    else:
        names = f"`{action.metavar or action.dest}`"
    details = _formatter("x")._expand_help(action) if action.help else ""   # (%(default)s as --help shows it)
    if action.required and action.option_strings:
        details += " (required)"
    if action.default not in (None, False, argparse.SUPPRESS, []) and action.nargs != 0 and action.option_strings:
        if "default" not in details.lower():
            details += f" (default: {action.default})"
    return f"| {names} | {escape(details)} |"


def _parser_section(parser: argparse.ArgumentParser, name: str, help_text: str, level: int) -> list[str]:
    """The lines of one parser's section: heading, description, usage and every argument; a parser with
    subcommands (`robot init`, `robot check`) gets a row per subcommand and a section of its own for each."""
    subcommands = [action for action in parser._actions if isinstance(action, argparse._SubParsersAction)]
    positional = [action for action in parser._actions if not action.option_strings and action not in subcommands]
    optional = [action for action in parser._actions
                if action.option_strings and not isinstance(action, argparse._HelpAction)]
    anchor = name.replace(" ", "-")
    parser.formatter_class = _formatter           # (a subcommand's parser is built with argparse's default)
    lines = [f"{'#' * level} `stdm-drake {name}` {{#{anchor}}}", "", escape(help_text[:1].upper() + help_text[1:]) + ".",
             "", "```text", parser.format_usage().strip(), "```", ""]
    for title, actions in (("Arguments", positional), ("Options", optional)):
        if actions:
            lines += [f"**{title}**", "", "| argument | what it does |", "|---|---|"]
            lines += [_argument_row(action) for action in actions]
            lines.append("")
    for action in subcommands:
        helps = {choice.dest: choice.help or "" for choice in action._choices_actions}
        lines += ["**Subcommands**", "", "| subcommand | what it does |", "|---|---|"]
        lines += [f"| [`{sub}`](#{anchor}-{sub}) | {escape(helps.get(sub, ''))} |" for sub in action.choices]
        lines.append("")
        for sub, subparser in action.choices.items():
            lines += _parser_section(subparser, f"{name} {sub}", helps.get(sub, "") or sub, level + 1)
    return lines


def command_section(name: str, module_name: str, help_text: str) -> str:
    """One subcommand's section: its description, usage and every argument, from the parser it really builds,
    with a section for each of its own subcommands."""
    from stdm_drake.cli import CommandParser
    module = importlib.import_module(module_name)
    parser = CommandParser(prog=f"stdm-drake {name}", description=help_text, formatter_class=_formatter)
    module.add_arguments(parser)
    lines = _parser_section(parser, name, help_text, 2)
    lines.append(f"`-h`, `--help` prints this; the command is module `{module_name}`.")
    return "\n".join(lines) + "\n"


def cli_page() -> str:
    """The command-line reference page."""
    from stdm_drake.cli import COMMANDS, DESCRIPTION
    lines = ["# Command-line reference", "",
             "Generated at every build from the argument parsers themselves (`stdm_drake.cli.COMMANDS`: each "
             "subcommand's module and its `add_arguments`), so it says what `stdm-drake COMMAND --help` says.", "",
             escape(DESCRIPTION), "",
             "A file argument written `stdm-drake:models/NAME`, `stdm-drake:trajectories/NAME` or "
             "`stdm-drake:controllers/NAME` names a file shipped with the package, from any folder.", "",
             "| command | what |", "|---|---|"]
    lines += [f"| [`{name}`](#{name}) | {escape(help_text)} |" for name, (_, help_text) in COMMANDS.items()]
    lines.append("")
    lines += [command_section(name, module_name, help_text)
              for name, (module_name, help_text) in COMMANDS.items()]
    return "\n".join(lines)


# -------------------------------------------------------------------------------------------------------- hooks

SOURCE_COMMENT = re.compile(r"<!--\s*=.*?-->", re.S)   # (the form tools/check_doc_numbers.py reads)


def on_page_markdown(markdown, **kwargs):
    """A page without its number-source comments (module docstring)."""
    return SOURCE_COMMENT.sub("", markdown)


def on_config(config, **kwargs):
    """Expand the nav entry of the API index into one page per module."""
    os.environ.setdefault("DRAKE_ALLOW_NETWORK", "meshcat")
    modules = package_modules()

    def expand(items):
        result = []
        for item in items or []:
            if isinstance(item, dict):
                ((title, value),) = item.items()
                if value == API_INDEX:
                    result.append({title: api_nav(modules)})
                elif isinstance(value, list):
                    result.append({title: expand(value)})
                else:
                    result.append(item)
            else:
                result.append(item)
        return result

    config["nav"] = expand(config["nav"])
    return config


FIGURE_SUFFIXES = (".png", ".svg", ".jpg", ".jpeg", ".gif")


def on_files(files, config, **kwargs):
    """Add the generated pages, and put the figures of docs/results/ back into the site: mkdocs.yml leaves the
    results folder out (its tables and JSON are read in the repository), but a page that shows a figure
    (`![...](results/reality_gap/closed_loop.png)`) needs the image beside it on the site. A figure a page shows
    that is not there is a warning, so the strict build fails on it."""
    from mkdocs.structure.files import File, InclusionLevel
    for file in files:
        if file.src_uri.startswith("results/") and file.src_uri.lower().endswith(FIGURE_SUFFIXES):
            file.inclusion = InclusionLevel.INCLUDED
    modules = package_modules()
    generated = {API_INDEX: api_index(modules), CLI_PAGE: cli_page(),
                 "benchmarks.md": (ROOT / "BENCHMARKS.md").read_text(encoding="utf-8")}
    generated.update({api_page_uri(name): api_page(name) for name, _ in modules})
    for uri, content in generated.items():
        files.append(File.generated(config, uri, content=content))
    return files
