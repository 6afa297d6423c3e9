"""Check that every number the docs quote from a committed results file equals what the file holds.

    python tools/check_doc_numbers.py [PAGE ...]        (default: README.md, BENCHMARKS.md and docs/**/*.md but docs/results/)

A number on a page names its source with an HTML comment right after it (not shown on the rendered page):

    3 of 5<!-- = docs/results/realtime/loop_control_data.json: sum(run["solve_ms_p95"] < 2 for run in
    r["periods"]["2 ms"]["runs"] if run["model"] == "D") -->

The expression after the colon is evaluated with `r`, the file's content (a JSON file's value; a CSV file's
rows as dicts of strings; with several files, comma separated, `r` is the first and `r0`, `r1`, ... each), and `len sum min max abs round sorted any all float int math geomean next` (and zip, range, list, set, dict, tuple). Its value is
a number, or a tuple of numbers for a range ("0.75-1.22x") or an interval ("1.28x [1.26, 1.30]"), and must
equal the number(s) written just before the comment to the digits written (590 matches 590.3; 1.10 does not
match 1.097). A comment may span lines. Exit status 0 when every quoted number matches, 1 otherwise (each
mismatch one line: page:line, the number written, what the file gives).
"""
from __future__ import annotations

import csv
import functools
import json
import math
import pathlib
import re
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
SOURCE = re.compile(r"<!--\s*=\s*(?P<file>[^:\s,]+(?:\s*,\s*[^:\s,]+)*)\s*:\s*(?P<expression>.*?)\s*-->", re.S)
# a written number: digits with thousands commas, decimals, an exponent ("1.7e-8", "1.7 x 10^-8" is not used);
# a minus sign only where it cannot be a range's dash ("0.75-1.22")
# (not a digit inside a word: "p95", "run2"; the exponent either case)
NUMBER = re.compile(r"(?:(?<![\w.\]%)])-)?(?<![\w.])\d{1,3}(?:,\d{3})+(?:\.\d+)?(?![\d,])"
                    r"|(?:(?<![\w.\]%)])-)?(?<![\w.,])\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")
# between the last number and its source comment: at most a short unit ("590 s", "1.15x", "9.4 minutes")
ADJACENT = re.compile(r"[^\d]{0,16}$")


def geomean(values) -> float:
    values = list(values)
    return math.exp(sum(math.log(value) for value in values) / len(values))


NAMES = dict(len=len, sum=sum, min=min, max=max, abs=abs, round=round, sorted=sorted, any=any, all=all, float=float,
             int=int, math=math, geomean=geomean, zip=zip, range=range, list=list, set=set, dict=dict, tuple=tuple,
             next=next)


def load(path: pathlib.Path):
    """A results file's content: JSON's value, or a CSV file's rows (dicts of strings); read once while it is
    unchanged (the expressions only read it: none sorts, pops or assigns in place)."""
    status = path.stat()
    return _read(path, status.st_mtime_ns, status.st_size)


@functools.lru_cache(maxsize=None)
def _read(path: pathlib.Path, modified_ns: int, size: int):
    if path.suffix == ".csv":
        with path.open(newline="") as stream:
            return list(csv.DictReader(stream))
    if path.suffix == ".jsonl":
        return [json.loads(line) for line in path.read_text().split("\n") if line.strip()]   # (not splitlines: U+2028 in a string)
    return json.loads(path.read_text())


def tolerance(written: str) -> float:
    """Half a unit of the last digit written ("590" 0.5, "1.097" 0.0005, "1.7e-8" 0.05e-8)."""
    mantissa, _, exponent = written.replace(",", "").lower().partition("e")
    decimals = len(mantissa.partition(".")[2])
    return 0.5 * 10 ** (-decimals) * 10 ** int(exponent or 0) * (1 + 1e-9)


def matches(written: str, value) -> bool:
    try:
        value = float(value)
    except (TypeError, ValueError):
        return False
    return math.isfinite(value) and abs(value - float(written.replace(",", ""))) <= tolerance(written)


def quoted_numbers(text: str, end: int, count: int) -> list[str]:
    """The last `count` numbers written in `text` before `end` (and after the previous source comment); none
    unless the last of them stands right before the comment (at most a short unit between)."""
    start = text.rfind("-->", 0, end)
    before = text[start + 3 if start >= 0 else 0:end]
    before = re.sub(r"`[^`]*`", " ", before)   # (a command or file name in code quotes holds no quoted number)
    found = list(NUMBER.finditer(before))
    if not count or not found or not ADJACENT.fullmatch(before[found[-1].end():]):
        return []
    return [match.group(0) for match in found[-count:]]


def committed_files(root: pathlib.Path) -> set[str] | None:
    """The files git tracks in `root` (None when it is not a git checkout: a test's folder)."""
    result = subprocess.run(["git", "-C", str(root), "ls-files"], capture_output=True, text=True)
    return set(result.stdout.splitlines()) if result.returncode == 0 else None


def check_page(page: pathlib.Path, root: pathlib.Path = ROOT) -> tuple[int, list[str]]:
    """(how many numbers the page quotes from a file, one line per mismatch)."""
    text = page.read_text()
    name = page.relative_to(root) if page.is_relative_to(root) else page
    checked, failures = 0, []
    tracked = committed_files(root) if "<!-- =" in text else None
    for found in SOURCE.finditer(text):
        line = text.count("\n", 0, found.start()) + 1
        where = f"{name}:{line}"
        names = [name.strip() for name in found["file"].split(",")]
        sources = [root / name for name in names]
        missing = [name for name, source in zip(names, sources)
                   if not source.is_file() or (tracked is not None and name not in tracked)]
        if missing:
            failures.append(f"{where}: {', '.join(missing)}: not a committed results file")
            continue
        try:
            contents = {f"r{index}": load(source) for index, source in enumerate(sources)}
            scope = {"__builtins__": {}, **NAMES, "r": contents["r0"], **contents}   # (globals: seen in a generator)
            value = eval(found["expression"], scope)  # noqa: S307
        except Exception as error:   # (a wrong key or expression: the page's claim cannot be traced)
            failures.append(f"{where}: {found['file']}: {found['expression']!r} fails: {type(error).__name__}: {error}")
            continue
        values = list(value) if isinstance(value, (tuple, list)) else [value]
        written = quoted_numbers(text, found.start(), len(values))
        checked += 1
        if not values:
            failures.append(f"{where}: {found['file']}: {found['expression']!r} gives no value")
        elif len(written) < len(values):
            failures.append(f"{where}: {len(values)} number(s) expected before the comment, found {written}")
        elif not all(matches(number, value) for number, value in zip(written, values)):
            shown = ", ".join(f"{float(v):.6g}" if isinstance(v, (int, float)) else repr(v) for v in values)
            failures.append(f"{where}: the page says {', '.join(written)}; {found['file']} gives {shown}")
    return checked, failures


def pages(root: pathlib.Path = ROOT) -> list[pathlib.Path]:
    """The pages: README.md, BENCHMARKS.md and docs/**/*.md, not the results under docs/results/ (sources, whose
    reports, e.g. an audit's, may quote this tool's comments)."""
    results = root / "docs" / "results"
    return [root / "README.md", root / "BENCHMARKS.md",
            *sorted(path for path in (root / "docs").rglob("*.md") if not path.is_relative_to(results))]


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    total, failures = 0, []
    for page in [pathlib.Path(name).resolve() for name in argv] or pages():
        if not page.is_file():
            print(f"check_doc_numbers.py: error: {page} is not a page", file=sys.stderr)
            return 2
        checked, failed = check_page(page)
        total += checked
        failures += failed
    print("\n".join(failures + [f"{total} quoted numbers checked, {len(failures)} mismatched"]))
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
