"""The `stdm-drake` command line: one subcommand per stage of the data flow.

Each subcommand is one thin module in `stdm_drake.commands` with `add_arguments(parser)` and
`run(args) -> int` over its stage's library; modules are imported only when their command runs, so
`stdm-drake collect` does not pay for importing PyTorch and `stdm-drake train` does not pay for Drake.
"""
from __future__ import annotations

import argparse
import codecs
import contextlib
import errno
import importlib
import locale
import logging
import os
import pathlib
import re
import signal
import sys

from stdm_drake import interrupts
from stdm_drake.errors import InputError, deferred_warnings
from stdm_drake.files import line_text, printable_text
from stdm_drake.outputs import command_outputs, release_locks
from stdm_drake.paths import expand_shipped

# name -> (module, one-line help)
COMMANDS = {
    "robot": ("stdm_drake.commands.robot",
              "a starting robot config from a URDF or SDF (init), and the checks of a robot config (check)"),
    "collect": ("stdm_drake.commands.collect", "simulate a robot under a data protocol and write a dataset"),
    "import": ("stdm_drake.commands.import_log",
               "a real robot's log (UR RTDE CSV, ROS 2 bag) as a dataset: resampled, split, checked"),
    "inspect": ("stdm_drake.commands.inspect", "print a summary of a dataset file"),
    "train": ("stdm_drake.commands.train", "train D/P/DE/PE dynamics models, with or without the derivative loss"),
    "identify": ("stdm_drake.commands.identify",
                 "identify the robot's link inertias and joint friction from a dataset (physically consistent)"),
    "evaluate": ("stdm_drake.commands.evaluate", "one-step and multi-step test errors of a trained model on a dataset"),
    "sine-sum": ("stdm_drake.commands.sine_sum", "the paper's sine-sum activation study (Fig. 6-8, Table 1)"),
    "compare": ("stdm_drake.commands.compare",
                "which model for this robot: every kind fitted on its data, open and closed loop, a recommendation"),
    "mpc": ("stdm_drake.commands.mpc",
            "closed-loop MPC of the plant with the plant itself and learned models as predictors"),
    "mbrl": ("stdm_drake.commands.mbrl",
             "the model-based RL loop: act with the model's MPC, collect the closed loop's data, refit, N rounds"),
    "export": ("stdm_drake.commands.export",
               "a trained model outside Python: ONNX graphs (model and Jacobians) or Drake MultilayerPerceptron systems"),
    "view": ("stdm_drake.commands.view",
             "Meshcat: recorded robot beside a learned model's open-loop prediction (ghost)"),
    "reproduce": ("stdm_drake.commands.reproduce",
                  "the paper's experiments end to end for a robot, with a report beside their numbers"),
}


class CommandParser(argparse.ArgumentParser):
    """argparse with its errors as one line (`stdm-drake CMD: error: ...; see --help`), exit status 2."""

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {line_text(message)} (see {self.prog} --help)\n")   # (a name's line break)


def error_line(error: BaseException) -> str:
    """One line for the user: the message's first line, with the file an OSError names; the toolbox's own messages
    (an InputError, a FileNotFoundError it raised with its message) whole, a name's line break in them escaped;
    every character that is not printable escaped (a terminal escape, U+202E)."""
    if isinstance(error, OSError) and error.strerror:
        if error.filename:
            return f"{error.strerror}: {line_text(error.filename)}"
        # (every file stdm-drake writes is named in its errors: one that names none is the standard output)
        return f"cannot write the standard output: {error.strerror}" if error.errno == errno.ENOSPC else error.strerror
    text = str(error).strip()
    if not text:
        return type(error).__name__
    if isinstance(error, (InputError, OSError)):   # (one line already: a line break in it is a name's)
        return line_text(text)
    return printable_text(text.splitlines()[0])


class RepeatedWarnings(logging.Filter):
    """Lets each distinct message of Drake's logger through once (the model file's line number aside:
    one warning per kind of problem, not one per joint and per plant built) and counts the rest."""

    def __init__(self):
        super().__init__()
        self.seen, self.left_out = set(), 0

    def filter(self, record: logging.LogRecord) -> bool:
        if record.getMessage().startswith("Meshcat listening for connections"):
            return False   # (the commands print the URL where a person is to open it: --meshcat)
        key = re.sub(r":\d+: ", ": ", record.getMessage())
        if key in self.seen:
            self.left_out += 1
            return False
        self.seen.add(key)
        return True


class HeldLines(logging.Handler):
    """The robot's own load-time lines as `errors.warn` lines: printed when the command succeeds (a refusal for
    another reason is its one line). (The records still reach the root logger's handlers, a test's too.)"""

    def __init__(self):
        super().__init__(logging.WARNING)

    def emit(self, record: logging.LogRecord) -> None:
        from stdm_drake.errors import warn
        warn(record.getMessage())


@contextlib.contextmanager
def drake_warnings_once(command: str):
    """While a command runs, Drake's INFO lines are left out and its parser warnings (it builds several plants from
    one description) are shown once each; afterwards one line says how many repeats were left out. The robot's own load-time lines
    (`robots.robot`: a replaced inertia, unmodelled joint effects, missing meshes), said each time the robot is
    built, are shown once each too, when the command succeeds (`HeldLines`)."""
    logger, repeated = logging.getLogger("drake"), RepeatedWarnings()
    robot_logger, robot_lines, held = logging.getLogger("stdm_drake.robots.robot"), RepeatedWarnings(), HeldLines()
    level = logger.level   # (Drake's INFO lines, a solver's progress such as Clarabel's, are not the user's)
    logger.setLevel(max(level, logging.WARNING))
    logger.addFilter(repeated)
    robot_logger.addFilter(robot_lines)
    robot_logger.addHandler(held)
    try:
        yield repeated
    finally:
        logger.setLevel(level)
        logger.removeFilter(repeated)
        robot_logger.removeFilter(robot_lines)
        robot_logger.removeHandler(held)
        if repeated.left_out:
            print(f"stdm-drake {command}: {repeated.left_out} repeats of Drake's warnings above left out",
                  file=sys.stderr)


DESCRIPTION = "The `stdm-drake` command line: one subcommand per stage of the data flow."   # (not __doc__: gone
                                                                                        # under python -OO)


HDF5_DRIVERS = ("sec2", "stdio", "core")   # HDF5_DRIVER values that keep a dataset one file at its path


def _can_be_made_writable(folder: str) -> bool:
    """Whether `folder` is a writable folder, or could be made as one: a folder made and removed in it (or
    in its nearest existing ancestor) tells, also for root, for whom os.access says yes to /proc."""
    import tempfile
    path = pathlib.Path(folder).absolute()
    while not os.path.lexists(path) and path != path.parent:
        path = path.parent
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".stdm-drake-probe.", dir=path))
    except OSError:
        return False
    return True


def main(argv: list[str] | None = None) -> int:
    for stream in (sys.stdout, sys.stderr):   # a stream that cannot encode a unit's ² (PYTHONIOENCODING=ascii):
        if stream is not None and hasattr(stream, "reconfigure") and \
                codecs.lookup(stream.encoding or "utf-8").name != "utf-8":   # escaped, never an error after the work
            stream.reconfigure(errors="backslashreplace")
    program = argv is None   # (the `stdm-drake` program itself, not a call from Python)
    argv = sys.argv[1:] if argv is None else list(argv)
    parser = CommandParser(prog="stdm-drake", description=DESCRIPTION)
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for name, (_, help_text) in COMMANDS.items():
        subparsers.add_parser(name, help=help_text, add_help=False)
    if not argv:
        parser.print_help(sys.stderr)
        return 2
    if argv[0] not in COMMANDS:
        try:
            parser.parse_args(argv)  # --help exits 0; an unknown command exits 2 with one line
        except SystemExit as exit_:
            return int(exit_.code or 0)
        return 2
    name = argv[0]
    if name == "mpc":   # a control step's small matrix products lose to BLAS thread hand-offs: one thread (before
        for variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):   # numpy loads; a value the user set is kept)
            os.environ.setdefault(variable, "1")
    try:
        os.getcwd()
    except FileNotFoundError:   # (PyTorch and Drake fail on it at import, before any message could be given)
        print(f"stdm-drake {name}: error: the working folder no longer exists (deleted?); cd to a folder that "
              "does", file=sys.stderr)
        return 2
    encoding = locale.getpreferredencoding(False)
    if codecs.lookup(encoding).name != "utf-8":   # (Drake fails to initialize: a traceback at import)
        print(f"stdm-drake {name}: error: the locale's text encoding is {encoding}; Drake needs UTF-8: set "
              "LC_ALL=C.UTF-8", file=sys.stderr)
        return 2
    threads = os.environ.get("OMP_NUM_THREADS")
    if threads is not None and not re.fullmatch(r"\s*[1-9][0-9]{0,5}\s*(,\s*[1-9][0-9]{0,5}\s*)*", threads):
        # (OpenMP, loaded with the imports, would print two warnings about it and go on without it)
        print(f"stdm-drake {name}: error: OMP_NUM_THREADS={threads[:40]!r} is not a thread count (positive "
              "integers, comma-separated per nesting level); set one or unset it", file=sys.stderr)
        return 2
    driver = os.environ.get("HDF5_DRIVER")
    if driver and driver.strip().lower() not in HDF5_DRIVERS:
        # (HDF5 segfaults on a driver it lacks; split, family and the others write other files than the one named)
        print(f"stdm-drake {name}: error: HDF5_DRIVER={driver[:40]!r}: stdm-drake reads and writes each dataset as "
              f"one HDF5 file, with the {', '.join(HDF5_DRIVERS)} driver; unset it", file=sys.stderr)
        return 2
    config_folder = os.environ.get("MPLCONFIGDIR")
    if config_folder and not _can_be_made_writable(config_folder):
        # (Matplotlib, imported for figures, would warn in two lines and keep its cache in a temporary folder)
        print(f"stdm-drake {name}: error: MPLCONFIGDIR={config_folder[:80]!r} is not a folder this user can write "
              "(Matplotlib keeps its cache there); set one or unset it", file=sys.stderr)
        return 2
    if os.environ.get("MPLBACKEND"):   # (Matplotlib's import refuses a backend it lacks: after a run's work)
        try:
            import matplotlib  # noqa: F401
        except ValueError:
            print(f"stdm-drake {name}: error: MPLBACKEND={os.environ['MPLBACKEND'][:40]!r} is no Matplotlib backend; "
                  "stdm-drake draws its figures into files with agg: unset it", file=sys.stderr)
            return 2
    try:
        # Ctrl-C, SIGTERM, SIGHUP: through every `finally`, from the imports on (the program's own run: until exit)
        with interrupts.signals_as_exceptions(until_exit=program):
            status = run_command(name, argv[1:])
            if interrupts.received() is None:
                return status
            raise KeyboardInterrupt   # a library swallowed the signal: the run did not end as asked
    except KeyboardInterrupt as error:
        status, what = interrupts.ending(error if isinstance(error, interrupts.Terminated) else None)
    except Exception:
        if interrupts.received() is None:
            raise
        status, what = interrupts.ending()   # a library turned the signal into its own error (pydrake: ImportError)
    release_locks()   # (a signal as the run ended may have cut its own release short; signals are ignored now)
    close_progress_bars()
    print(f"stdm-drake {name}: {what}", file=sys.stderr)
    ray = sys.modules.get("ray")
    if program and not (ray is not None and ray.is_initialized()):   # (a local Ray instance ends in Ray's exit hook)
        # Held-out run 41: once in 13 Ctrl-Cs to `collect --workers 2`, the program printed its line and then hung
        # 150 s in Python's exit hooks (which join the stopped worker pool's thread). Its outputs are whole or
        # absent, its locks released and its workers stopped by now: it ends without them.
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(status)
    return status


class PrintableLines:
    """A text stream that writes what it is given with every character that is not printable, other than the line
    break and the tab, as its Python escape ("\\r", "\\x1b", "\\u2028"): a name a command prints (a file, a
    joint, a robot) cannot end a line, overwrite it or drive the terminal. Everything else is the stream's own."""

    def __init__(self, stream):
        self._stream = stream

    def write(self, text: str) -> int:
        self._stream.write(printable_text(text, keep="\n\t"))
        return len(text)

    def __getattr__(self, name):
        return getattr(self._stream, name)


@contextlib.contextmanager
def printable_output():
    """The command's standard output as PrintableLines while it runs (progress bars and warnings go to standard
    error, whose one error line `error_line` escapes)."""
    stream = sys.stdout
    sys.stdout = PrintableLines(stream)
    try:
        yield
    finally:
        sys.stdout = stream


def decimal_numbers_only(parser: argparse.ArgumentParser) -> None:
    """Every int or float option of `parser` (and of its subcommands) read in ASCII decimal digits only
    (`config.decimal_number`): `--epochs 1_0` or `--count ٢` is argparse's one-line error, not 10 or 2."""
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for subparser in action.choices.values():
                decimal_numbers_only(subparser)
        elif action.type in (int, float):
            action.type = _DECIMAL[action.type]


def _decimal(kind: type):
    def read(text: str):
        from stdm_drake.config import decimal_number   # (a command's own imports bring it: nothing more to load)
        try:
            return decimal_number(text, kind)
        except ValueError:
            raise argparse.ArgumentTypeError(f"invalid {kind.__name__} value: {text!r} (ASCII decimal digits)") from None
    return read


_DECIMAL = {int: _decimal(int), float: _decimal(float)}


def run_command(name: str, argv: list[str]) -> int:
    """Parse `argv` for command `name` and run it: its exit status; bad input is one line and status 2."""
    try:  # stdm-drake:controllers/pid.yaml names a shipped file, from any folder
        argv = [expand_shipped(argument) for argument in argv]
    except ValueError as error:
        print(f"stdm-drake {name}: error: {error_line(error)}", file=sys.stderr)
        return 2
    module = importlib.import_module(COMMANDS[name][0])   # (a signal inside an import waits for its end)
    command_parser = CommandParser(prog=f"stdm-drake {name}", description=COMMANDS[name][1])
    module.add_arguments(command_parser)
    decimal_numbers_only(command_parser)
    interrupts.raise_deferred()   # (a signal inside the imports: before any argument error is printed)
    try:
        args = command_parser.parse_args(argv)
    except SystemExit as exit_:  # --help (0) or a malformed command line (2, one line printed)
        return int(exit_.code or 0)
    try:
        with command_outputs(name, argv, options=frozenset(command_parser._option_string_actions)), \
                drake_warnings_once(name), deferred_warnings(), printable_output():
            return int(module.run(args) or 0)   # (a failing command prints its one error line only)
    except BrokenPipeError:   # the reader of the output went away (`stdm-drake inspect x.h5 | head -2`): quietly
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())   # (no second error when Python flushes)
        return 128 + signal.SIGPIPE
    except (ValueError, OSError) as error:  # InputError is a ValueError; OSError: files, folders, HDF5
        close_progress_bars()
        interrupts.raise_deferred()   # (a signal that arrived before the refusal ends the run: its one line only)
        interrupts.raise_if_received()
        print(f"stdm-drake {name}: error: {error_line(error)}", file=sys.stderr)
        return 2


def close_progress_bars() -> None:
    """Close the progress bars a failed or interrupted command left open, so that its last line on the
    terminal is the error (a bar closed later would redraw itself after it)."""
    tqdm = sys.modules.get("tqdm")
    for bar in list(getattr(getattr(tqdm, "tqdm", None), "_instances", None) or ()):
        bar.close()


if __name__ == "__main__":
    sys.exit(main())
