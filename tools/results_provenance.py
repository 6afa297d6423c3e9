"""Which committed results files name the commit their run ran on, and the index of those that do not.

    python tools/results_provenance.py            (check: exit 1, one line per file, where a results file names no
                                                   commit and is not in the index, or the index is stale)
    python tools/results_provenance.py --write    (rewrite docs/results/provenance_index.json from git)

A results file (JSON, JSONL or CSV under docs/results/) names its run's commit in a `provenance` object ("commit",
or "frozen_copy_of" for a held-out run on a frozen copy), a top-level "commit", or a "commit" column. Files written
before the studies recorded provenance (issue 55) cannot be given the commit they ran on after the fact; the index
lists each with the commit that first added it to git ("committed_in": the code the run used was that commit or an
earlier one, plus whatever the working tree held), so that the gap is named file by file and no new file joins it:
the test suite runs the check (tests/test_provenance.py).
"""
from __future__ import annotations

import csv
import json
import pathlib
import subprocess
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
RESULTS = ROOT / "docs" / "results"
INDEX = RESULTS / "provenance_index.json"
SUFFIXES = (".json", ".jsonl", ".csv")


def names_commit(path: pathlib.Path) -> bool:
    """Whether the results file at `path` names the commit its run ran on."""
    text = path.read_text(encoding="utf-8")
    if path.suffix == ".csv":
        header = next(csv.reader(text.splitlines()), [])
        return "commit" in header
    documents = ([json.loads(line) for line in text.splitlines()[:1] if line.strip()] if path.suffix == ".jsonl"
                 else [json.loads(text)])
    for document in documents:
        if not isinstance(document, dict):
            continue
        record = document.get("provenance")
        if isinstance(record, dict) and (record.get("commit") or record.get("frozen_copy_of")):
            return True
        if isinstance(document.get("commit"), str) and document["commit"]:
            return True
    return False


def results_files() -> list[pathlib.Path]:
    """The tracked results files (git ls-files), the index itself left out."""
    listed = subprocess.run(["git", "-C", str(ROOT), "ls-files", "docs/results"], capture_output=True, text=True,
                            check=True).stdout.split()
    return [ROOT / name for name in listed if name.endswith(SUFFIXES) and ROOT / name != INDEX]


def first_commit(relative: str) -> str:
    """The commit that first added `relative` (following no renames), as git records it."""
    out = subprocess.run(["git", "-C", str(ROOT), "log", "--diff-filter=A", "--format=%H", "--", relative],
                         capture_output=True, text=True, check=True).stdout.split()
    return out[-1] if out else ""


def problems() -> list[str]:
    """One line per results file that names no commit and is not in the index, and per index entry that is
    stale (its file gone, or now naming its commit)."""
    index = json.loads(INDEX.read_text())["files"] if INDEX.exists() else {}
    found = []
    lacking = set()
    for path in results_files():
        relative = path.relative_to(ROOT).as_posix()
        if not names_commit(path):
            lacking.add(relative)
            if relative not in index:
                found.append(f"{relative}: names no commit and is not in {INDEX.relative_to(ROOT).as_posix()}; "
                             "record the run's provenance (stdm_drake.provenance)")
    for relative in sorted(set(index) - lacking):
        found.append(f"{INDEX.relative_to(ROOT).as_posix()}: {relative} is listed but is gone or names its commit")
    return found


def write_index() -> int:
    """Rewrite the index from git; its own provenance names the commit it was made on (a clean checkout: refused
    otherwise, in one line)."""
    sys.path.insert(0, str(ROOT))
    from stdm_drake.provenance import dirty_refusal, provenance
    record = provenance("python tools/results_provenance.py --write", root=ROOT)
    refusal = dirty_refusal(record)
    if refusal is not None:
        raise SystemExit(f"results_provenance.py: error: {refusal}")
    files = {}
    for path in results_files():
        if not names_commit(path):
            relative = path.relative_to(ROOT).as_posix()
            files[relative] = {"committed_in": first_commit(relative)}
    INDEX.write_text(json.dumps({
        "about": "results files that name no commit their run ran on (written before the studies recorded "
                 "provenance); committed_in: the commit that first added the file to git, so the code of its run "
                 "was that commit or an earlier one, with whatever the working tree held then. Regenerate with "
                 "python tools/results_provenance.py --write.",
        "provenance": record, "files": files}, indent=1, sort_keys=True) + "\n")
    return len(files)


def main(argv=None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    if argv == ["--write"]:
        print(f"{write_index()} files without a commit -> {INDEX.relative_to(ROOT)}")
        return 0
    if argv:
        print(__doc__.strip().splitlines()[0], file=sys.stderr)
        return 2
    found = problems()
    for line in found:
        print(line)
    return 1 if found else 0


if __name__ == "__main__":
    sys.exit(main())
