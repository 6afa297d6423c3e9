"""Errors that mean "bad input": the CLI prints them as one line and exits with status 2; warnings a
command owes are held until it has succeeded."""
import contextlib
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
