"""What a results file records of the run that made it, so that each of its numbers can be traced: the code
(stdm-drake's version, and the git commit of the checkout it runs from, with whether that checkout had
uncommitted changes to tracked code), the command line and the machine.

The studies (tools/study.py) and benchmarks (tools/bench_*.py) take it at their start, since that is the code
they import, and refuse a checkout with uncommitted changes unless told (`--allow-dirty`, recorded here);
`reproduce`, `sine-sum` and `mpc` record it in their results files (`results_header`).
"""
from __future__ import annotations

import os
import pathlib
import platform
import re
import subprocess
from importlib.metadata import PackageNotFoundError, version
from stdm_drake.outputs import running_command, written_by

PACKAGE_FOLDER = pathlib.Path(__file__).resolve().parent
DIRTY_HINT = ("commit them (the results then name the code that made them) or pass --allow-dirty "
              "(recorded in the results)")


# What a results file records is the code; the results themselves (docs/, the Markdown pages, BENCHMARKS.md)
# change with every run that writes them, so a change there does not make the code unclean.
NOT_CODE = (":(exclude)docs", ":(exclude)*.md")


def source_state(root: pathlib.Path | None = None) -> dict:
    """{"commit": the checkout's HEAD (None when `root` is not the top of a git checkout: a regular install,
    even one inside another checkout), "clean": True when no tracked file of code differs from it (untracked
    files, docs/ and Markdown pages aside; False without a checkout, where the code cannot be traced)}.
    `root`: the checkout (default: the one this package is in)."""
    root = PACKAGE_FOLDER.parent if root is None else pathlib.Path(root)

    def git(*arguments):
        try:
            result = subprocess.run(["git", "-C", str(root), *arguments], capture_output=True, text=True, timeout=60)
        except (OSError, subprocess.TimeoutExpired):   # no git on this machine
            return None
        return result.stdout.strip() if result.returncode == 0 else None
    top = git("rev-parse", "--show-toplevel")
    if not top or pathlib.Path(top).resolve() != root.resolve():
        return dict(commit=None, clean=False)
    commit = git("rev-parse", "--verify", "HEAD")
    changes = git("--no-optional-locks", "status", "--porcelain", "--untracked-files=no", "--", ".", *NOT_CODE)
    return dict(commit=commit, clean=bool(commit) and changes == "")


def machine_description(threads: int | None = None) -> str:
    """CPU model, cores, Python and package versions (and torch threads if given), one line."""
    cpuinfo = pathlib.Path("/proc/cpuinfo")
    names = [line.split(":", 1)[1].strip() for line in (cpuinfo.read_text().splitlines() if cpuinfo.exists() else [])
             if line.startswith("model name")]
    model = names[0] if names else (platform.processor() or "unknown CPU")
    packages = []
    for name in ("torch", "numpy", "drake"):
        try:
            packages.append(f"{name} {version(name)}")
        except PackageNotFoundError:
            continue
    text = f"{model}, {os.cpu_count()} cores; Python {platform.python_version()}, {', '.join(packages)}"
    return text + (f"; torch threads {threads}" if threads is not None else "")


def package_version() -> str | None:
    try:
        return version("stdm-drake")
    except PackageNotFoundError:   # a checkout run without an install (tools/study.py)
        return None


FOLDER_OPTIONS = ("--folder", "--data", "-o", "--output")
ABSOLUTE_PATH = re.compile(r"(?<![\w.~])/[^\s=,:;]+")


def recorded_command(program: str, arguments: list[str], folders=FOLDER_OPTIONS,
                     root: pathlib.Path | None = None) -> str:
    """The command line a results file records: `program` and its `arguments`, with no path of this machine:
    the value of each option in `folders` is written DIR, any other absolute path DIR/<its name> (relative to
    the checkout `root`, default this package's, when inside it)."""
    root = PACKAGE_FOLDER.parent if root is None else pathlib.Path(root)

    def path_shown(match) -> str:
        path = pathlib.Path(match.group(0))
        return str(path.relative_to(root)) if path.is_relative_to(root) else f"DIR/{path.name}"

    def shown(previous: str, value: str) -> str:
        option, equals, attached = value.partition("=")
        if equals and option.startswith("--"):
            return f"{option}={shown(option, attached)}"
        if previous in folders:
            return "DIR"
        return ABSOLUTE_PATH.sub(path_shown, value)   # (a path alone, or inside a value: --model D=/x/model.pt)
    return " ".join([program, *(shown(previous, value) for previous, value in zip([""] + list(arguments), arguments))])


def command_provenance() -> dict:
    """The provenance of the stdm-drake command now running (`stdm-drake NAME ARGS`, as recorded_command
    writes it; "stdm-drake" alone when used as a library), for the results files of `reproduce`, the main
    job and the MPC study."""
    line = running_command(with_arguments=True)
    return provenance(recorded_command("stdm-drake", line or []))


def results_header() -> dict:
    """What the results file of a stdm-drake command opens with: {"written_by": "stdm-drake COMMAND",
    "provenance": command_provenance()}."""
    return dict(written_by=written_by(), provenance=command_provenance())


def provenance(command: str, allow_dirty: bool = False, threads: int | None = None,
               root: pathlib.Path | None = None) -> dict:
    """The record of a run: {"commit", "clean", "allow_dirty" (only when set), "command", "machine",
    "stdm_drake" (the installed version, None without an install)}. `command`: the command line as the
    results should show it (no folder of this machine in it: see `recorded_command`)."""
    record = dict(source_state(root), command=command, machine=machine_description(threads),
                  stdm_drake=package_version())
    if allow_dirty:
        record["allow_dirty"] = True
    return record


def dirty_refusal(state: dict) -> str | None:
    """The one-line reason a run that commits its results refuses this checkout, or None when it is clean."""
    if state["clean"]:
        return None
    if state["commit"] is None:
        return "this is not a git checkout, so the results could not name their code; pass --allow-dirty to run anyway"
    return f"the checkout has uncommitted changes to tracked code (git status); {DIRTY_HINT}"
