"""Check the package's function-level imports of its own modules against what they claim (issue 60).

    python tools/check_lazy_imports.py

Outside `cli.py` and `commands/` (the command line's boundary), the package imports its own modules at the top,
except where the imported module loads a heavy library that the importing module does not load by itself; such an
import says which on its line or the line above: `# lazy: pydrake, h5py` (or `# lazy: the compiled extension ...`
for `stdm_drake._core`). `tests/test_structure.py` checks that every such import carries the mark; this script
checks that the marks are true: each module is imported alone in a fresh interpreter and the heavy libraries it
loaded are recorded, then

  - a marked import whose target loads none of the named libraries beyond its importer's is reported (it could
    move to the top);
  - an unmarked function-level import of the package's own modules is reported.

Exit status 0 when every mark holds, 1 otherwise (one line per finding). It starts one Python per module involved,
about a minute on 2 cores.
"""
from __future__ import annotations

import ast
import json
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
PACKAGE = ROOT / "stdm_drake"
HEAVY = ("torch", "pydrake", "ray", "onnx", "matplotlib", "h5py")
MARK = "# lazy:"
PROBE = ("import importlib, json, sys; importlib.import_module(sys.argv[1]); "
         f"print(json.dumps([name for name in {HEAVY!r} if name in sys.modules]))")


def module_name(path: pathlib.Path) -> str:
    return ".".join(path.relative_to(ROOT).with_suffix("").parts).removesuffix(".__init__")


def function_level_own_imports(path: pathlib.Path) -> list[tuple[ast.stmt, str]]:
    """(statement, the text of its lines and the line above) of every import of a `stdm_drake` module inside a
    function of `path`."""
    source = path.read_text()
    lines = source.splitlines()
    found = []

    def walk(node: ast.AST, in_function: bool) -> None:
        for child in ast.iter_child_nodes(node):
            if in_function and isinstance(child, (ast.Import, ast.ImportFrom)):
                names = [child.module or ""] if isinstance(child, ast.ImportFrom) else [a.name for a in child.names]
                if all(name == "stdm_drake" or name.startswith("stdm_drake.") for name in names):
                    found.append((child, "\n".join(lines[max(child.lineno - 2, 0):child.end_lineno])))
            walk(child, in_function or isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef, ast.Lambda)))

    walk(ast.parse(source), False)
    return found


def checked_files() -> list[pathlib.Path]:
    """The package's modules outside the command line's boundary."""
    return [path for path in sorted(PACKAGE.rglob("*.py"))
            if path.name != "cli.py" or path.parent != PACKAGE
            if "commands" not in path.relative_to(PACKAGE).parts]


def targets(statement: ast.stmt, modules: set[str]) -> list[str]:
    """The modules an import statement loads (`from a import b`: a.b where b is a module, else a)."""
    if isinstance(statement, ast.ImportFrom):
        return [f"{statement.module}.{alias.name}" if f"{statement.module}.{alias.name}" in modules
                else statement.module for alias in statement.names]
    return [alias.name for alias in statement.names]


def heavy_libraries(module: str) -> set[str]:
    """The heavy libraries importing `module` alone loads (a fresh interpreter)."""
    run = subprocess.run([sys.executable, "-c", PROBE, module], capture_output=True, text=True, cwd=ROOT,
                         env={"DRAKE_ALLOW_NETWORK": "meshcat", "PATH": "/usr/bin:/bin"}, check=True)
    return set(json.loads(run.stdout))


def main() -> int:
    modules = {module_name(path) for path in PACKAGE.rglob("*.py")}
    sites = [(path, statement, text) for path in checked_files()
             for statement, text in function_level_own_imports(path)]
    cache: dict[str, set[str]] = {}

    def libraries(module: str) -> set[str]:
        if module not in cache:
            cache[module] = heavy_libraries(module)
        return cache[module]

    findings = []
    for path, statement, text in sites:
        where = f"{path.relative_to(ROOT)}:{statement.lineno}"
        if MARK not in text:
            findings.append(f"{where}: a function-level import of the package's own module without `{MARK}`")
            continue
        if any(target == "stdm_drake._core" or target.startswith("stdm_drake._core")
               for target in targets(statement, modules | {"stdm_drake._core"})):
            continue   # the compiled extension: absent where its build failed, checked where it is imported
        extra = set().union(*(libraries(target) for target in targets(statement, modules))) - libraries(
            module_name(path))
        if not extra:
            findings.append(f"{where}: marked lazy, but its module loads no heavy library its importer does not "
                            "load: import it at the top")
    for line in findings:
        print(line)
    print(f"{len(sites)} function-level imports of the package's own modules outside the command line, "
          f"{len(findings)} findings")
    return 1 if findings else 0


if __name__ == "__main__":
    sys.exit(main())
