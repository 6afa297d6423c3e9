"""Shared by the benchmarks in tools/: the machine they ran on, and writing their BENCHMARKS.md part."""
import os
import pathlib
import platform
import subprocess
import sys
from importlib.metadata import PackageNotFoundError, version

ROOT = pathlib.Path(__file__).resolve().parents[1]
BENCHMARKS_FILE = ROOT / "BENCHMARKS.md"
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from stdm_drake.files import write_text_atomic  # noqa: E402


def machine_description(threads: int | None = None) -> str:
    """CPU model, cores, Python and package versions (and torch threads if given), one Markdown line."""
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


def provenance() -> dict:
    """The commit the benchmark's code is, and whether the tree was clean (untracked files aside): what a result
    file names so that its numbers can be traced."""
    def git(*arguments):
        return subprocess.run(["git", "-C", str(ROOT), *arguments], capture_output=True, text=True).stdout.strip()
    return dict(commit=git("rev-parse", "HEAD"), clean=git("status", "--porcelain", "--untracked-files=no") == "")


def recorded_command(program: str, arguments: list[str], folders=("--folder", "--data", "-o", "--output")) -> str:
    """The command line a result file records: `program` and its `arguments`, the value of each option in
    `folders` written DIR (no path of this machine in a committed file)."""
    return " ".join([program, *("DIR" if previous in folders else value
                                for previous, value in zip([""] + arguments, arguments))])


def write_benchmark_section(section: str, title: str, body: str, path: pathlib.Path = BENCHMARKS_FILE) -> None:
    """Replace (or add) the subsection '### title' under '## section' of BENCHMARKS.md, leaving every
    other part of the file as it is."""
    heading = f"## {section}"
    text = path.read_text() if path.exists() else "# Benchmarks\n"
    lines = text.splitlines()
    block = [f"### {title}", "", *body.strip("\n").splitlines(), ""]
    try:
        start_section = lines.index(heading)
    except ValueError:
        lines += ["", heading, "", *block]
    else:
        end = next((i for i in range(start_section + 1, len(lines)) if lines[i].startswith("## ")), len(lines))
        start = next((i for i in range(start_section + 1, end) if lines[i] == f"### {title}"), None)
        if start is None:
            lines[end:end] = ([""] if lines[end - 1].strip() else []) + block
        else:
            stop = next((i for i in range(start + 1, end) if lines[i].startswith("### ")), end)
            lines[start:stop] = block
    write_text_atomic(path, "\n".join(lines).rstrip("\n") + "\n")
