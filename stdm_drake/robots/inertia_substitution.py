"""What Drake's parsers simulate in place of a link inertia no rigid body has, and the one line the toolbox says
for it (`robot.Robot` reports it and records it in datasets; `description` reads the inertias)."""
import contextlib
import logging
import math

import numpy as np

from stdm_drake.robots.description import Description, Inertial

# What Drake's parsers put in place of a rotational inertia no body has (a negative principal moment, moments
# that break the triangle inequality; `RotationalInertia.CouldBePhysicallyValid`): a solid sphere of the link's
# mass at the density of water about the link's centre of mass (drake/multibody/parsing/detail_common.cc,
# ParseSpatialInertia). The toolbox simulates what Drake simulates, and says so in one line per link.
SUBSTITUTE_DENSITY = 1000.0   # kg/m³


def inertia_substitution(inertial: Inertial) -> str | None:
    """What Drake's parser simulates in place of a link's rotational inertia that fails Drake's own test
    (`RotationalInertia.CouldBePhysicallyValid`: a negative principal moment, or moments that break the
    triangle inequality beyond Drake's round-off): the file's moments, why no body has them, and the solid
    sphere Drake uses (the link's mass m kg at SUBSTITUTE_DENSITY: I = 2/5 m r² about each axis through the
    centre of mass, r = (3 m / (4 pi density))^(1/3) m). None for an inertia Drake takes as written, a massless
    frame, or a mass these checks cannot read."""
    from pydrake.multibody.tree import RotationalInertia
    mass, inertia = inertial.mass, inertial.inertia
    if mass is None or not mass > 0 or not np.isfinite(inertia).all():
        return None
    if RotationalInertia(inertia[0, 0], inertia[1, 1], inertia[2, 2], inertia[0, 1], inertia[0, 2],
                         inertia[1, 2]).CouldBePhysicallyValid():
        return None
    moments = np.linalg.eigvalsh(inertia)
    why = ("one of them negative" if moments[0] < 0 else
           f"breaking the triangle inequality by {(moments[2] - moments[0] - moments[1]) / moments[2]:.1%} of the largest")
    radius = (3.0 * mass / (4.0 * math.pi * SUBSTITUTE_DENSITY)) ** (1.0 / 3.0)
    sphere = 0.4 * mass * radius ** 2
    return (f"principal moments {_moments_text(inertia)} kg m², {why}: no rigid body has them, and Drake simulates "
            f"the link as a solid sphere of its {mass:g} kg at {SUBSTITUTE_DENSITY:g} kg/m³ instead ({sphere:.4g} kg m² "
            "about each axis through the centre of mass)")


# Drake's parser warnings for an inertia it replaces (several lines each; the robot's own line says it once)
DRAKE_INERTIA_WARNINGS = ("While parsing inertia matrix", "has invalid inertia")


@contextlib.contextmanager
def drake_inertia_warnings_left_out(leave_out: bool):
    """While Drake parses a description whose replaced inertias were reported (`leave_out`), its own warnings for
    them are left out; every other warning passes."""
    drake = logging.getLogger("drake")

    def keep(record) -> bool:
        return not any(text in record.getMessage() for text in DRAKE_INERTIA_WARNINGS)

    if leave_out:   # (first, so that no other filter counts them: `cli.drake_warnings_once`)
        drake.filters.insert(0, keep)
    try:
        yield
    finally:
        drake.removeFilter(keep)


def inertia_substitutions(description: Description) -> dict[str, str]:
    """Per link whose inertia Drake replaces, what it uses instead (`inertia_substitution`); an included file's link
    as "file: link"."""
    found = {link: inertia_substitution(inertial) for link, inertial in [*description.links.items(),
                                                                         *description.included.items()] if inertial}
    return {link: text for link, text in found.items() if text is not None}


def _moments_text(inertia: np.ndarray) -> str:
    """The principal moments (ascending) of a finite (3, 3) inertia, as "[a, b, c]"."""
    return "[" + ", ".join(f"{value:.4g}" for value in np.linalg.eigvalsh(inertia)) + "]"
