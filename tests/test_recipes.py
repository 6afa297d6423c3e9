"""Every command the README and the documentation show is run, so that none can rot (docs/guides/install.md,
"This documentation").

A fenced code block is marked by an HTML comment on the line right before its opening fence:

    <!-- recipe: NAME -->         a ```bash block runs with `bash -e -o pipefail`, a ```python block with this
                                  Python; a failing command fails the test
    <!-- recipe-file: PATH -->    the block is written to PATH in the page's folder, for the recipes after it
    <!-- not-a-recipe: REASON --> nothing runs; the reason says why it cannot (a second machine, a download, ...)
    <!-- recipe: NAME; verdicts: learned, not learned -->
                                  as `recipe`, and the verdicts the block prints (`train`'s per seed, `evaluate`'s),
                                  in order, must be these: what the page says of them is what a user will see

Each page's recipes run in their order on the page, in one empty folder of their own outside the checkout
(never the checkout as the working folder), with this Python's `bin/` first on PATH; files shipped with the
package are named `stdm-drake:models/...` and so on. The sizes the pages show are the sizes that run (small:
seconds each; each guide says in a line how to scale up); there is no table of size substitutions.

The marking itself is checked on every run (fast): in the README, docs/index.md and docs/guides/, a shell block
that calls `stdm-drake`, or a Python block that imports `stdm_drake`, must be marked one way or the other, and a
recipe may name a shipped file only with the `stdm-drake:` prefix. The studies' reports (docs/*.md) are records
of past runs, not instructions: their marked blocks run, unmarked ones are left alone.
"""
from __future__ import annotations

import dataclasses
import os
import pathlib
import re
import subprocess
import sys
import time

import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
SHELLS = {"bash", "sh", "shell", "console", "zsh"}
MARK = re.compile(r"^\s*<!--\s*(recipe|recipe-file|not-a-recipe)\s*:\s*(.*?)\s*-->\s*$")
FENCE = re.compile(r"^(\s*)(`{3,}|~{3,})\s*([\w+-]*)")
BLOCK_TIMEOUT = 300   # s per block; every block shown takes seconds to about half a minute


@dataclasses.dataclass
class Block:
    page: pathlib.Path
    line: int           # of the opening fence, 1-based
    language: str
    code: str
    mark: str | None    # "recipe", "recipe-file", "not-a-recipe" or None
    argument: str       # the recipe's name, the file's path, or the reason

    def where(self) -> str:
        return f"{self.page.relative_to(ROOT)}:{self.line}"

    @property
    def name(self) -> str:
        """The recipe's name (its argument up to the first ';')."""
        return self.argument.split(";")[0].strip()

    @property
    def verdicts(self) -> list[str] | None:
        """The verdicts the mark states ("learned" / "not learned", in order), or None where it states none."""
        for part in self.argument.split(";")[1:]:
            key, _, value = part.partition(":")
            if key.strip() == "verdicts":
                return [verdict.strip() for verdict in value.split(",")]
        return None


VERDICT = re.compile(r"-> (learned \(at the noise floor\)|learned|has not learned the dynamics)\s*$")


def printed_verdicts(output: str) -> list[str]:
    """The learning verdicts a block printed, in order, as "learned" / "not learned": each `train` seed's (the
    first model row under its "seed N on the ... split" line) and each `evaluate`'s ("... against the
    physics-free baselines: ... -> VERDICT")."""
    found, lines = [], output.splitlines()
    for index, line in enumerate(lines):
        if re.match(r"^seed \d+ on the \w+ split \(", line) and index + 2 < len(lines):
            match = VERDICT.search(lines[index + 2])
        elif "against the physics-free baselines:" in line:
            match = VERDICT.search(line)
        else:
            continue
        if match:
            found.append("not learned" if match.group(1).startswith("has not") else "learned")
    return found


def pages() -> list[pathlib.Path]:
    """The README and every Markdown page of the site (docs/results, left out of the site, aside)."""
    return [ROOT / "README.md"] + sorted(path for path in DOCS.rglob("*.md")
                                         if (DOCS / "results") not in path.parents)


def checked(page: pathlib.Path) -> bool:
    """Whether every command block of `page` must be marked: the README, the home page and the guides."""
    return page == ROOT / "README.md" or page == DOCS / "index.md" or (DOCS / "guides") in page.parents


def blocks(page: pathlib.Path) -> list[Block]:
    """The fenced code blocks of a page, each with the mark on the line before its fence."""
    lines = page.read_text(encoding="utf-8").splitlines()
    found, index = [], 0
    while index < len(lines):
        opening = FENCE.match(lines[index])
        if not opening:
            index += 1
            continue
        indent, fence, language = opening.groups()
        end = index + 1
        while end < len(lines) and not re.match(rf"^\s*{re.escape(fence[0])}{{{len(fence)},}}\s*$", lines[end]):
            end += 1
        code = "\n".join(line[len(indent):] if line.startswith(indent) else line.lstrip()
                         for line in lines[index + 1:end]) + "\n"
        mark = MARK.match(lines[index - 1]) if index else None
        found.append(Block(page, index + 1, language.lower(), code, mark.group(1) if mark else None,
                           mark.group(2) if mark else ""))
        index = end + 1
    return found


def is_command_block(block: Block) -> bool:
    """A block that shows something a user runs: a shell block calling stdm-drake, or Python importing
    stdm_drake (also any block whose lines start with `stdm-drake `)."""
    calls = re.search(r"(^|[\s;&|(])stdm-drake\s", block.code, re.MULTILINE) is not None
    if block.language in SHELLS:
        return calls
    if block.language in ("python", "py"):
        return re.search(r"^\s*(from|import)\s+stdm_drake\b", block.code, re.MULTILINE) is not None
    return re.search(r"^\s*\$?\s*stdm-drake\s", block.code, re.MULTILINE) is not None


# ------------------------------------------------------------------------------------------- marking (fast)

def test_every_command_block_is_marked():
    unmarked = [block.where() for page in pages() if checked(page) for block in blocks(page)
                if block.mark is None and is_command_block(block)]
    assert not unmarked, ("blocks that show commands but are neither `<!-- recipe: NAME -->` nor "
                          f"`<!-- not-a-recipe: REASON -->`: {unmarked}")


def test_marks_are_well_formed():
    problems = []
    for page in pages():
        names = set()
        for block in blocks(page):
            if block.mark is None:
                continue
            if not block.argument:
                problems.append(f"{block.where()}: {block.mark} without its name, path or reason")
            if block.mark == "recipe":
                if block.language not in ("bash", "python"):
                    problems.append(f"{block.where()}: a recipe is a ```bash or ```python block, not {block.language!r}")
                if block.name in names:
                    problems.append(f"{block.where()}: recipe name {block.name!r} twice on the page")
                names.add(block.name)
                extra = [part.strip() for part in block.argument.split(";")[1:]]
                if any(not part.startswith("verdicts:") for part in extra) or \
                        (block.verdicts is not None and not set(block.verdicts) <= {"learned", "not learned"}):
                    problems.append(f"{block.where()}: after the name only '; verdicts: learned, not learned, ...'")
            if block.mark == "recipe-file" and (pathlib.PurePath(block.argument).is_absolute()
                                                or ".." in pathlib.PurePath(block.argument).parts):
                problems.append(f"{block.where()}: recipe-file {block.argument!r} must be a path inside the folder")
        marks = [line for line in page.read_text(encoding="utf-8").splitlines() if MARK.match(line)]
        fenced = sum(block.mark is not None for block in blocks(page))
        if len(marks) != fenced:
            problems.append(f"{page.relative_to(ROOT)}: {len(marks) - fenced} mark(s) not right before a fence")
    assert not problems, problems


def test_recipes_name_shipped_files_by_prefix():
    """A recipe runs outside the checkout: models/, controllers/ and trajectories/ only as `stdm-drake:...`."""
    relative = re.compile(r"(?<![\w:/.-])(models|controllers|trajectories)/[\w.-]+\.(yaml|urdf|sdf)")
    found = [f"{block.where()}: {match.group(0)}" for page in pages() for block in blocks(page)
             if block.mark in ("recipe", "recipe-file") for match in relative.finditer(block.code)]
    assert not found, f"shipped files named by a checkout path (use stdm-drake:FOLDER/NAME): {found}"


def test_readme_is_short_and_keeps_the_two_commands():
    readme = (ROOT / "README.md").read_text(encoding="utf-8")
    assert len(readme.splitlines()) <= 200
    ci = [line for line in (ROOT / ".ci" / "run").read_text().splitlines() if "pytest" in line]
    assert ci and all(line in readme.splitlines() for line in ci), "README's test command is not .ci/run's"
    assert ".venv/bin/stdm-drake reproduce --quick" in readme


# -------------------------------------------------------------------------------------------- running (slow)

RECIPE_PAGES = [page for page in pages() if any(block.mark == "recipe" for block in blocks(page))]


def environment() -> dict:
    environment = {key: value for key, value in os.environ.items()
                   if key not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV", "MPLBACKEND")}
    environment["PATH"] = os.pathsep.join([str(pathlib.Path(sys.executable).parent), environment.get("PATH", "")])
    environment["DRAKE_ALLOW_NETWORK"] = "meshcat"
    return environment


@pytest.mark.slow
@pytest.mark.parametrize("page", RECIPE_PAGES, ids=[str(page.relative_to(ROOT)) for page in RECIPE_PAGES])
def test_recipes_run(page, tmp_path):
    folder = tmp_path / "work"
    folder.mkdir()
    assert ROOT not in folder.resolve().parents and folder.resolve() != ROOT
    env, times, wrong = environment(), [], []
    for block in blocks(page):
        if block.mark == "recipe-file":
            target = folder / block.argument
            target.parent.mkdir(parents=True, exist_ok=True)
            target.write_text(block.code, encoding="utf-8")
            continue
        if block.mark != "recipe":
            continue
        script = folder / f".recipe-{block.line}.{'py' if block.language == 'python' else 'sh'}"
        script.write_text(block.code, encoding="utf-8")
        command = ([sys.executable, str(script)] if block.language == "python"
                   else ["bash", "-e", "-o", "pipefail", str(script)])
        started = time.perf_counter()
        result = subprocess.run(command, cwd=folder, env=env, capture_output=True, text=True,
                                timeout=BLOCK_TIMEOUT)
        script.unlink()
        verdicts = printed_verdicts(result.stdout)
        times.append(f"{block.name} {time.perf_counter() - started:.1f} s" + (f" {verdicts}" if verdicts else ""))
        assert result.returncode == 0, (
            f"recipe {block.name!r} ({block.where()}) exited {result.returncode}:\n"
            f"{result.stdout[-3000:]}\n{result.stderr[-3000:]}")
        if (block.verdicts is not None or verdicts) and verdicts != block.verdicts:
            wrong.append(f"recipe {block.name!r} ({block.where()}) printed the verdicts {verdicts}; its page states "
                         f"{block.verdicts} (mark it '<!-- recipe: {block.name}; verdicts: ... -->' and say so on "
                         "the page)")
    print(f"{page.relative_to(ROOT)}: " + ", ".join(times))
    assert not wrong, wrong


def test_verdicts_are_read_as_train_and_evaluate_print_them():
    train = ("seed 0 on the test split (2 trajectories, 198 transitions; held out ...), one-step MSE:\n"
             "                 q [rad^2] v [(rad/s)^2]  against the Euler step (q) / 'v unchanged' (v)\n"
             "  D              1.0e-05   2.0e-03  1.2x better / 5.52x worse -> has not learned the dynamics\n"
             "  Euler step     1.2e-05   1.0e-02  (q + dt v; 'v unchanged')\n"
             "seed 1 on the test split (2 trajectories, 198 transitions; held out ...), one-step MSE:\n"
             "                 q [rad^2] v [(rad/s)^2]  against the Euler step (q) / 'v unchanged' (v)\n"
             "  D              1.0e-07   2.0e-05  120x better / 500x better -> learned\n")
    evaluate = "D against the physics-free baselines: one-step q 1.03x better ..., v 1.2x better -> learned (at the noise floor)\n"
    assert printed_verdicts(train + evaluate) == ["not learned", "learned", "learned"]
    block = Block(ROOT / "README.md", 1, "bash", "", "recipe", "train; verdicts: learned, not learned")
    assert block.name == "train" and block.verdicts == ["learned", "not learned"]
    assert Block(ROOT / "README.md", 1, "bash", "", "recipe", "train").verdicts is None
