"""stdm-drake: collect UR-10 data in Drake, learn state-transition dynamics models with
derivative learning (Kim, Lee & Ryu, IEEE Access 2022), and use them in Drake diagrams."""
import os
import sys

# A remote Drake package must fail at once (offline machines); local Meshcat keeps working.
os.environ.setdefault("DRAKE_ALLOW_NETWORK", "meshcat")


def _is_the_program() -> bool:
    """Whether this process is the `stdm-drake` program (the console script or `python -m stdm_drake.cli`), by
    its own command line (a pool's spawned worker is handed the parent's sys.argv, not its orig_argv)."""
    argv = sys.orig_argv
    return (any(os.path.basename(argument) == "stdm-drake" for argument in argv[1:2])
            or any(flag == "-m" and module == "stdm_drake.cli" for flag, module in zip(argv, argv[1:])))


def _standard_streams_open() -> None:
    """Standard input, output and error the program was started without (`2>&-`) are opened on the null device:
    otherwise the first file the program opens takes their number, and whatever a library writes to the
    terminal (Drake's log, HDF5's error stack) lands in it, a dataset or a checkpoint. Their text goes nowhere,
    as the user asked; the exit status stands."""
    for fd, name in enumerate(("stdin", "stdout", "stderr")):
        try:
            os.fstat(fd)
        except OSError:
            null = os.open(os.devnull, os.O_RDONLY if fd == 0 else os.O_WRONLY)
            if null != fd:
                os.dup2(null, fd)
                os.close(null)
            setattr(sys, name, open(fd, "r" if fd == 0 else "w", closefd=False))


if _is_the_program():   # a signal during the imports ends the program at once with one line
    _standard_streams_open()
    from stdm_drake.interrupts import exit_at_once_on_signals
    exit_at_once_on_signals()

__version__ = "0.1.0"
