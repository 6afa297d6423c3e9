"""Shared by the benchmarks in tools/ and the studies: the provenance a run records (stdm_drake/provenance.py),
refusing a checkout with uncommitted changes before a run whose results are committed, and writing a
benchmark's part of BENCHMARKS.md."""
import pathlib
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
BENCHMARKS_FILE = ROOT / "BENCHMARKS.md"
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

from stdm_drake.errors import InputError  # noqa: E402
from stdm_drake.files import write_text_atomic  # noqa: E402
from stdm_drake.provenance import (dirty_refusal, machine_description, provenance,  # noqa: E402,F401
                                   recorded_command)


def add_record_arguments(parser) -> None:
    """--allow-dirty, for a benchmark or study whose results are committed (see `start_record`)."""
    parser.add_argument("--allow-dirty", action="store_true",
                        help="run on a checkout with uncommitted changes to tracked code (recorded in the results)")


def start_record(program: str, arguments: list[str], allow_dirty: bool, writes: bool = True,
                 threads: int | None = None) -> dict:
    """At a run's start (the code it imports is the checkout's now): its provenance (stdm_drake/provenance.py),
    the command written by `recorded_command`. A run that `writes` results to be committed refuses a checkout
    with uncommitted changes unless `allow_dirty`: InputError, one line, before any work."""
    origin = provenance(recorded_command(program, arguments, root=ROOT), allow_dirty=allow_dirty, threads=threads,
                        root=ROOT)
    reason = dirty_refusal(origin)
    if writes and reason and not allow_dirty:
        raise InputError(reason)
    return origin


def start_benchmark(parser, argv: list[str] | None = None, threads: int | None = None):
    """Parse a benchmark's command line (with --allow-dirty added) and take its provenance at the start:
    (args, origin). A run that will --write its results refuses a checkout with uncommitted changes (one line
    on stderr, exit status 2) unless --allow-dirty."""
    add_record_arguments(parser)
    argv = sys.argv[1:] if argv is None else list(argv)
    args = parser.parse_args(argv)
    try:
        origin = start_record(f"python tools/{pathlib.Path(parser.prog).name}", argv, args.allow_dirty,
                              writes=bool(getattr(args, "write", False)), threads=threads)
    except InputError as error:
        print(f"{parser.prog}: error: {error}", file=sys.stderr)
        raise SystemExit(2)
    return args, origin


def command_line(origin: dict) -> str:
    """The Markdown line naming a run's command and code: "Command: `python tools/...` (commit 1234567,
    clean tree)."."""
    commit = (origin.get("commit") or "unknown")[:7]
    state = "clean tree" if origin.get("clean") else "uncommitted changes, --allow-dirty"
    return f"Command: `{origin['command']}` (commit {commit}, {state})."


def markdown_tables(body: str) -> list[list[dict]]:
    """Every Markdown table of `body` as its rows, each a dict from the header's cells to the row's (strings as
    printed, the bold marks taken off)."""
    tables, header = [], None
    for line in body.splitlines() + [""]:
        cells = [cell.strip().strip("*").strip() for cell in line.strip().strip("|").split("|")]
        if not line.lstrip().startswith("|"):
            header = None
        elif header is None:
            header = cells
            tables.append([])
        elif not all(set(cell) <= set("-: ") for cell in cells):
            tables[-1].append(dict(zip(header, cells)))
    return tables


def write_benchmark_section(section: str, title: str, body: str, origin: dict,
                            path: pathlib.Path = BENCHMARKS_FILE, record: bool = True,
                            name: str | None = None) -> pathlib.Path | None:
    """Replace (or add) the subsection '### title' under '## section' of BENCHMARKS.md with `body` and the line
    naming the run's command and commit (`origin`: start_benchmark's), leaving every other part as it is; with
    `record` also the run's results file beside the other results, docs/results/benchmarks/NAME.json (NAME: `name`,
    else the benchmark's file name): its provenance, the section's text and its tables as rows (what the pages that
    quote a benchmark name as their source). Returns that file's path (None without `record`)."""
    heading = f"## {section}"
    text = path.read_text() if path.exists() else "# Benchmarks\n"
    lines = text.splitlines()
    block = [f"### {title}", "", *body.strip("\n").splitlines(), command_line(origin), ""]
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
    if not record:
        return None
    import json
    name = name or pathlib.Path(origin["command"].split()[1]).stem   # "python tools/bench_x.py ...": bench_x
    results = path.parent / "docs" / "results" / "benchmarks" / f"{name}.json"
    results.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(results, json.dumps(dict(provenance=origin, section=section, title=title, text=body.strip("\n"),
                                               tables=markdown_tables(body)), indent=1, ensure_ascii=False) + "\n")
    return results
