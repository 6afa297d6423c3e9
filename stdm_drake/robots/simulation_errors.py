"""Drake's failures inside a simulation as one line (held-out run 31: a 1e5 kg payload, a link scaled 1e6 times or a
link inertia of 1e300 kg m² are within or beyond what the plant effects bound, and the plant's solver then fails
with a RuntimeError whose traceback reached the user)."""
from __future__ import annotations

import contextlib

from stdm_drake.errors import InputError

CAUSE = ("bodies far heavier, or with far more inertia, than the arm's others (the plant effects' payload, mass_scale "
         "or link_inertia, or the description's own masses) are the usual cause; bring them closer to the arm's")


def simulation_failure(error: RuntimeError, time: float | None = None) -> InputError:
    """The one-line error for Drake's `error` while simulating the plant (at `time` s where known): its first
    sentence and the usual cause."""
    first = " ".join(str(error).split()).split(". ")[0].rstrip(".")
    when = "" if time is None else f" at t = {time:.3g} s"
    return InputError(f"the plant's simulation failed{when} (Drake: {first}); {CAUSE}")


@contextlib.contextmanager
def simulation_errors(time=None):
    """Drake's RuntimeError inside the block as `simulation_failure`'s InputError; time: a callable giving the
    simulated time s when it failed (None: not known)."""
    try:
        yield
    except RuntimeError as error:
        raise simulation_failure(error, None if time is None else time()) from None
