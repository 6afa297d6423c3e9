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


if _is_the_program():   # a signal during the imports ends the program at once with one line
    from stdm_drake.interrupts import exit_at_once_on_signals
    exit_at_once_on_signals()

__version__ = "0.1.0"
