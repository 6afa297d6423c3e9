"""Time the README's first command from a fresh clone, as a new user runs it: setting up (a new virtual
environment, `pip install -q -e .`: the dependencies from the package index and the compiled core's build) and
the main job (`stdm-drake reproduce --quick`).

    python tools/time_first_command.py [--write] [--allow-dirty]

The clone is of this checkout's HEAD, in a temporary folder removed afterwards. --write records the times in
docs/results/install/first_command.json with the run's provenance (a checkout with uncommitted changes is
refused unless --allow-dirty); the README and the install guide quote that file.
"""
import argparse
import json
import os
import pathlib
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from benchmark_report import ROOT, start_benchmark  # noqa: E402

from stdm_drake.files import write_text_atomic  # noqa: E402

SETUP = "python3 -m venv .venv && .venv/bin/pip install -q -e ."
RUN = ".venv/bin/stdm-drake reproduce --quick"
RESULT = ROOT / "docs" / "results" / "install" / "first_command.json"


def timed(command: str, folder: pathlib.Path) -> float:
    """Wall seconds of `command` run by bash in `folder`; SystemExit with its last output lines if it fails."""
    started = time.perf_counter()
    result = subprocess.run(["bash", "-c", command], cwd=folder, capture_output=True, text=True,
                            env={key: value for key, value in os.environ.items() if key != "VIRTUAL_ENV"})
    if result.returncode != 0:
        lines = (result.stderr or result.stdout).strip().splitlines()
        raise SystemExit(f"time_first_command.py: `{command}` failed ({result.returncode})"
                         + (f": {lines[-1]}" if lines else ""))
    return time.perf_counter() - started


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="time_first_command.py", description=__doc__.splitlines()[0])
    parser.add_argument("--write", action="store_true", help=f"write {RESULT.relative_to(ROOT)}")
    args, origin = start_benchmark(parser, argv)
    with tempfile.TemporaryDirectory(prefix="first_command_") as folder:
        clone = pathlib.Path(folder) / "stdm-drake"
        timed(f"git clone -q {ROOT} {clone}", pathlib.Path(folder))
        setup = timed(SETUP, clone)
        print(f"set-up: {setup:.0f} s", flush=True)
        run = timed(RUN, clone)
        print(f"main job: {run:.0f} s; in all {setup + run:.0f} s", flush=True)
        report = (clone / "out" / "reproduce" / "report.html").is_file()
    if args.write:
        write_text_atomic(RESULT, json.dumps(dict(
            what="the README's first command from a fresh clone of the commit named: a new virtual environment and "
                 "`pip install -q -e .` (dependencies from the package index, the compiled core built), then the main "
                 "job on built-in defaults", setup_command=SETUP, run_command=RUN, provenance=origin,
            setup_seconds=round(setup, 1), run_seconds=round(run, 1), total_seconds=round(setup + run, 1),
            report_written=report), indent=1) + "\n")
        print(f"wrote {RESULT.relative_to(ROOT)}")
    return 0 if report else 1


if __name__ == "__main__":
    sys.exit(main())
