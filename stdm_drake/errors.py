"""Errors that mean "bad input": the CLI prints them as one line and exits with status 2; warnings a
command owes are held until it has succeeded; `check_seed`, every seed option's one check; `bound_text`, a bound
a refusal advises, printed so that the printed value is accepted."""
import contextlib
import math
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


def bound_text(value: float, *, at_least: bool, digits: int = 3) -> str:
    """`value` (a finite bound a refusal advises) with `digits` significant digits, rounded away from the refused
    side: up for "at least", down for "below" / "at most", so that a user who types the printed number is not
    refused again (held-out run 33: a Coulomb velocity scale refused with "at least 0.0588" was refused again at
    0.0588, the bound lying just above it)."""
    text = f"{value:.{digits}g}"
    if value == 0 or not math.isfinite(value) or (float(text) >= value if at_least else float(text) <= value):
        return text
    step = 10.0 ** (math.floor(math.log10(abs(value))) - digits + 1)
    shown = (math.ceil if at_least else math.floor)(value / step) * step
    text = f"{shown:.{digits}g}"
    while at_least and float(text) < value or not at_least and float(text) > value:   # (the product's rounding)
        shown += step if at_least else -step
        text = f"{shown:.{digits}g}"
    return text
