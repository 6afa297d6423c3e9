"""Errors that mean "bad input": the CLI prints them as one line and exits with status 2; warnings a
command owes are held until it has succeeded; `check_seed`, every seed option's one check."""
import contextlib
import operator
import sys


class InputError(ValueError):
    """Malformed config, wrong shapes, non-finite data, truncated or mismatched files."""


class PlanningError(InputError):
    """A requested pose or trajectory is unreachable or violates the robot's limits."""


_DEFERRED: list | None = None   # warning lines held back while a command runs (see `deferred_warnings`)


def warn(line: str) -> None:
    """One warning line on stderr; while a command runs (`deferred_warnings`), once it has succeeded, so
    that a command that fails prints its one error line only."""
    if _DEFERRED is not None:
        _DEFERRED.append(line)
    else:
        print(line, file=sys.stderr)


@contextlib.contextmanager
def deferred_warnings():
    """Hold `warn` lines back until the block ends without an exception, then print each once; an
    exception drops them (its one-line error says what is wrong)."""
    global _DEFERRED
    outer, _DEFERRED = _DEFERRED, []
    try:
        yield
        held = list(dict.fromkeys(_DEFERRED))
    finally:
        _DEFERRED = outer
    for line in held:
        warn(line)


def check_seed(label: str, value) -> int:
    """`value` as a seed of numpy's generators, or InputError (one line) unless it is a non-negative integer (they
    take any; torch's seeds, train's --seeds, have their own bound: 2^64-1)."""
    try:
        seed = None if isinstance(value, bool) else operator.index(value)
    except TypeError:
        seed = None
    if seed is None or seed < 0:
        raise InputError(f"{label} must be a non-negative integer (numpy's generators take any), got {value!r}")
    return seed
