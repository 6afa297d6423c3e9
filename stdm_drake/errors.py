"""Errors that mean "bad input": the CLI prints them as one line and exits with status 2."""


class InputError(ValueError):
    """Malformed config, wrong shapes, non-finite data, truncated or mismatched files."""


class PlanningError(InputError):
    """A requested pose or trajectory is unreachable or violates the robot's limits."""
