"""What the physics needs of an arm's inertias, checked on its finalized plant: each link's inertia within its
mass's reach, and a mass matrix M(home) the solvers can invert (every joint moves inertia about its axis, no two
joints move the same inertia, eigenvalues within double precision's reach). `robot.Robot.check_plant` checks the
description's plant; `plant.check_plant_effects` the plant as the effects change it (link inertias, mass scales,
payload). Each refusal is one InputError naming the link or joints and what they carry."""
import numpy as np

from pydrake.multibody.plant import MultibodyPlant

from stdm_drake.errors import InputError
from stdm_drake.robots.limit_checks import MAX_GYRATION_RADIUS

SINGULAR_MASS_MATRIX = 1e-10  # M(home)'s smallest eigenvalue over its largest at or below which it is refused
NO_INERTIA = 1e-12            # a joint's M_ii over the inertia its links carry about the joint at or below: none


def check_link_inertias(plant: MultibodyPlant, instance, where: str) -> None:
    """InputError unless every link of `instance` with a mass keeps its largest principal moment of inertia
    about its centre of mass within mass x MAX_GYRATION_RADIUS² (kg m²): mass farther out than any body reaches.
    (The published descriptions of pybullet_data and rtb-data reach 10 m at most.)"""
    for index in plant.GetBodyIndices(instance):
        body = plant.get_body(index)
        mass = body.default_mass()
        if not mass > 0:
            continue
        inertia = body.default_spatial_inertia()
        central = inertia.Shift(inertia.get_com()).CalcRotationalInertia().CopyToFullMatrix3()
        with np.errstate(all="ignore"):
            top = np.abs(np.linalg.eigvalsh(central)).max() if np.isfinite(central).all() else np.inf
            bound = mass * MAX_GYRATION_RADIUS ** 2
        if not top <= bound:
            raise InputError(f"{where}: link {body.name()!r} has a principal moment of inertia {top:.6g} kg m², beyond "
                             f"its mass x ({MAX_GYRATION_RADIUS:g} m)² = {bound:.6g} kg m² (its {mass:g} kg farther "
                             "out than any body reaches)")


def _inertia_carried(plant: MultibodyPlant, context, joint) -> float:
    """What the links outboard of `joint` carry about it: half the trace of their rotational inertia about the
    joint's child frame (kg m², a bound on their moment about any axis there) for a revolute joint, their mass
    (kg) for another."""
    bodies = plant.GetBodiesKinematicallyAffectedBy([joint.index()])
    composite = plant.CalcSpatialInertia(context, joint.frame_on_child(), bodies)
    if joint.type_name() != "revolute":
        return composite.get_mass()
    return 0.5 * np.trace(composite.CalcRotationalInertia().CopyToFullMatrix3())


def check_arm_inertias(plant: MultibodyPlant, instance, home: np.ndarray, where: str, context=None) -> None:
    """The checks of this module on a finalized plant at the arm's home (home: (n,) rad or m of `instance`): the
    links' inertias as the description states them and M(home) in a default context (context None), or M(home)
    alone in `context`, whose parameters may change the links (the plant effects' link inertias, mass scales)."""
    if context is None:
        check_link_inertias(plant, instance, where)
        context = plant.CreateDefaultContext()
    plant.SetPositions(context, instance, home)
    check_mass_matrix(plant, context, instance, where)


def check_mass_matrix(plant: MultibodyPlant, context, instance, where: str) -> None:
    """InputError unless M of `instance`'s joints at the context's positions is positive definite with its
    eigenvalues within 1 / SINGULAR_MASS_MATRIX of each other, whatever the file's links are (massless frames,
    point masses, thin rods); the message tells the three ways to fail apart:
      a joint that moves no inertia about its axis (its M_ii at most NO_INERTIA of what its links carry about it);
      joints that move the same inertia (M scaled to a unit diagonal, D^-1/2 M D^-1/2, is itself singular);
      else inertias that span more than double precision's reach (M's eigenvalues, named by the joints with the
      least and most inertia M_ii)."""
    joints = sorted((plant.get_joint(index) for index in plant.GetJointIndices(instance)
                     if plant.get_joint(index).num_velocities() > 0), key=lambda joint: joint.velocity_start())
    rows = [joint.velocity_start() for joint in joints]
    M = plant.CalcMassMatrix(context)[np.ix_(rows, rows)]
    with np.errstate(all="ignore"):
        finite = np.isfinite(M).all()
        eigenvalues = np.linalg.eigvalsh(M) if finite else np.full(len(rows), np.nan)
        if finite and eigenvalues[0] > SINGULAR_MASS_MATRIX * max(eigenvalues[-1], 0.0):
            return
        diagonal = np.diag(M)
        carried = np.array([_inertia_carried(plant, context, joint) for joint in joints])
    hint = ("the links it moves need a mass, and for a revolute joint an inertia about the axis or a centre of mass "
            "off it")
    # (a joint's rotor inertia, in M_ii and not in what its links carry, is inertia it moves)
    none = [joint.name() for joint, moved, links in zip(joints, diagonal, carried)
            if not (moved > 0 and moved > NO_INERTIA * links)]
    if none or not finite:
        name = none[0] if none else joints[0].name()
        raise InputError(f"{where}: arm joint {name!r} moves no inertia about its axis at home (the mass matrix M(home) "
                         f"is singular, smallest eigenvalue {eigenvalues[0]:.3g}); {hint}")
    scale = 1.0 / np.sqrt(diagonal)
    values, vectors = np.linalg.eigh(M * scale[:, None] * scale[None, :])
    if values[0] <= SINGULAR_MASS_MATRIX:
        first, second = sorted(np.argsort(-np.abs(vectors[:, 0]))[:2])
        raise InputError(f"{where}: arm joints {joints[first].name()!r} and {joints[second].name()!r} move the same "
                         f"inertia at home (the mass matrix M(home) is singular: one motion of the two moves nothing); "
                         "a link between them needs a mass or an inertia of its own, or their axes must differ")
    low, high = int(np.argmin(diagonal)), int(np.argmax(diagonal))
    unit = lambda index: "kg m²" if joints[index].type_name() == "revolute" else "kg"
    span = f"{eigenvalues[-1] / eigenvalues[0]:.3g}x" if eigenvalues[0] > 0 else "more than double precision resolves"
    raise InputError(f"{where}: the mass matrix M(home) spans {span} between its eigenvalues, beyond the "
                     f"{1 / SINGULAR_MASS_MATRIX:.0e}x that double precision keeps solvable: arm joint "
                     f"{joints[low].name()!r} moves {diagonal[low]:.3g} {unit(low)} and {joints[high].name()!r} "
                     f"{diagonal[high]:.3g} {unit(high)} with the others held; bring the links' inertias closer")
