"""The research studies' one command line: `python tools/study.py NAME [options]`.

    python tools/study.py --list                 the studies, one line each
    python tools/study.py NAME --help            a study's options
    python tools/study.py NAME [options]         run it (results in docs/results/<study>/ by default)

A study is a module of tools/studies/ (a plain folder, not installed with the package) with a one-line
docstring, `add_arguments(parser)` and `run(args) -> int`: the shape of the package's commands
(stdm_drake/commands/). The folder's other modules are code the studies share. Each study's design is in
docs/*.md, written before its runs. This file is the only one that puts the checkout on `sys.path`, so a
checkout without an install runs them; as `stdm-drake` does, it keeps Drake offline (Meshcat aside) and
prints bad input (an InputError, or an OSError naming a file) as one line with exit status 2.

Every study's results name the code that made them: the launcher takes the run's provenance at the start
(`args.provenance`: commit, clean tree, command with no folder of this machine, machine; see
stdm_drake/provenance.py) and each study writes it into its results JSON. A checkout with uncommitted changes
to tracked code is refused unless the command says `--allow-dirty` (recorded there too); a `--quick` run (its
results go to out/) and a study that writes no results (`WRITES_RESULTS = False`) are not.
"""
from __future__ import annotations

import ast
import functools
import importlib
import os
import pathlib
import sys

TOOLS = pathlib.Path(__file__).resolve().parent
ROOT = TOOLS.parent
STUDIES = TOOLS / "studies"
PROGRAM = "tools/study.py"


def on_path() -> None:
    """The checkout (for `stdm_drake` without an install) and tools/ (for `studies`, and the benchmark helpers
    a study shares) at the front of `sys.path`; spawned worker processes inherit it."""
    for folder in (TOOLS, ROOT):
        if str(folder) not in sys.path:
            sys.path.insert(0, str(folder))


@functools.cache
def studies() -> dict[str, str]:
    """NAME -> the first line of its docstring, for every study module of tools/studies/ (one that defines
    add_arguments and run; read without importing it). NAME is the module's name with '-' for '_'."""
    found = {}
    for path in sorted(STUDIES.glob("*.py")):
        tree = ast.parse(path.read_text(encoding="utf-8"), filename=str(path))
        functions = {node.name for node in tree.body if isinstance(node, ast.FunctionDef)}
        if {"add_arguments", "run"} <= functions:
            found[path.stem.replace("_", "-")] = ((ast.get_docstring(tree) or "").strip().splitlines() or [""])[0]
    return found


def load(name: str):
    """The module of study NAME (`studies.<name>`), imported with the checkout on the path."""
    on_path()
    return importlib.import_module(f"studies.{name.replace('-', '_')}")


def listing(known: dict[str, str]) -> str:
    width = max(map(len, known), default=0) + 2
    return "\n".join(f"  {name:<{width}}{line}" for name, line in known.items())


def main(argv: list[str] | None = None) -> int:
    os.environ.setdefault("DRAKE_ALLOW_NETWORK", "meshcat")   # (before Drake is imported: offline, Meshcat kept)
    argv = sys.argv[1:] if argv is None else list(argv)
    known = studies()
    usage = f"usage: {PROGRAM} NAME [options] | {PROGRAM} NAME --help | {PROGRAM} --list"
    if not argv or argv[0] in ("-h", "--help"):
        print(f"{usage}\n\nstudies:\n{listing(known)}", file=sys.stdout if argv else sys.stderr)
        return 0 if argv else 2
    if argv[0] == "--list":
        print(listing(known))
        return 0
    name = argv[0]
    if name not in known:
        print(f"{PROGRAM}: error: no study {name!r}; one of {', '.join(known)} (see {PROGRAM} --list)",
              file=sys.stderr)
        return 2
    module = load(name)
    from benchmark_report import add_record_arguments, start_record   # (tools/ is on the path: `load`)
    from stdm_drake.cli import CommandParser, error_line
    from stdm_drake.errors import InputError
    parser = CommandParser(prog=f"{PROGRAM} {name}", description=known[name])
    module.add_arguments(parser)
    add_record_arguments(parser)
    try:
        args = parser.parse_args(argv[1:])
    except SystemExit as exit_:   # --help (0) or a malformed command line (2, one line printed)
        return int(exit_.code or 0)
    try:
        writes = getattr(module, "WRITES_RESULTS", True) and not getattr(args, "quick", False)   # (--quick: out/)
        args.provenance = start_record(f"python {PROGRAM} {name}", argv[1:], args.allow_dirty, writes=writes)
        return int(module.run(args) or 0)
    except (InputError, OSError) as error:   # bad input; OSError: a file or folder (missing, unwritable, full disk)
        print(f"{PROGRAM} {name}: error: {error_line(error)}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
