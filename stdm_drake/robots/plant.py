"""Drake plants and simulators of a Robot: the plant + scene-graph builder, the held-torque simulator, joint
limits, rigid-body dynamics and the self-collision check."""
import dataclasses

import numpy as np

from pydrake.geometry import CollisionFilterDeclaration, GeometrySet
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlant, MultibodyPlantConfig
from pydrake.systems.framework import DiagramBuilder

from stdm_drake.errors import InputError
from stdm_drake.robots.effect_systems import (actuation_input, add_effect_systems, link_torque, measured_state_output,
                                              start_actuators)
from stdm_drake.robots.effects import PlantEffects, add_effects_to_plant, coulomb_torque, set_effect_parameters
from stdm_drake.robots.nested_models import nested_instances
from stdm_drake.robots.robot import Robot


DEFAULT_PLANT_TIME_STEP = 0.001   # s


def _default_multibody() -> MultibodyPlantConfig:
    return MultibodyPlantConfig(time_step=DEFAULT_PLANT_TIME_STEP, discrete_contact_approximation="sap")


@dataclasses.dataclass
class PlantConfig:
    """How the robot's plant is simulated.

    multibody: Drake's own `MultibodyPlantConfig` (time_step s, 0 for a continuous-time plant;
        discrete_contact_approximation "sap" here, Drake's other settings at Drake's defaults), as
        `AddMultibodyPlant` takes it.
    self_collision: keep contact between the robot's own (non-adjacent) links.
    effects: what the simulated plant has beyond the robot's description (`robots.effects`); None: the
        description as it is (the nominal model).
    """
    multibody: MultibodyPlantConfig = dataclasses.field(default_factory=_default_multibody)
    self_collision: bool = True
    effects: PlantEffects | None = None

    @classmethod
    def discrete(cls, time_step: float = DEFAULT_PLANT_TIME_STEP, **fields) -> "PlantConfig":
        """A discrete plant stepping every `time_step` s (the other settings as the default)."""
        config = cls(**fields)
        config.multibody.time_step = float(time_step)
        return config

    @classmethod
    def continuous(cls) -> "PlantConfig":
        """A continuous-time plant (time_step 0): for kinematics and dynamics queries."""
        return cls.discrete(0.0)

    @property
    def time_step(self) -> float:
        return self.multibody.time_step

    def __getstate__(self) -> dict:   # to worker processes as a dataset records it (Drake's config does not pickle)
        return self.record()

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(PlantConfig.from_record(state).__dict__)

    @classmethod
    def from_record(cls, record: dict | None, *, effects: bool = True) -> "PlantConfig":
        """`record`'s inverse, the plant a dataset records: its MultibodyPlantConfig fields (the others at this
        toolbox's defaults, one this Drake does not know left out), self_collision and, with `effects`, the
        effects (False: the description as it is, simulated as the data were). None or {}: the default plant."""
        import yaml
        from pydrake.common.yaml import yaml_dump_typed, yaml_load_typed
        record = dict(record or {})
        config = cls(self_collision=bool(record.pop("self_collision", True)))
        stored = record.pop("effects", None)
        known = yaml.safe_load(yaml_dump_typed(config.multibody)) or {}
        fields = {name: value for name, value in record.items() if name in known}
        if fields:
            config.multibody = yaml_load_typed(data=yaml.safe_dump(fields), defaults=config.multibody)
        config.effects = PlantEffects.from_record(stored) if effects and stored else None
        return config

    def record(self) -> dict:
        """What a dataset records of the plant: self_collision, every MultibodyPlantConfig field and, for an
        affected plant, its effects (`PlantEffects.record`)."""
        import yaml
        from pydrake.common.yaml import yaml_dump_typed
        record = dict(yaml.safe_load(yaml_dump_typed(self.multibody)) or {}, self_collision=self.self_collision)
        if self.effects is not None:
            record["effects"] = self.effects.record()
        return record

    def set_parameters(self, plant, plant_context) -> None:
        """The effects' parameters (per-link mass scales) in a context of a plant `make_plant` built."""
        if self.effects is not None:
            set_effect_parameters(plant, plant_context, self.effects)


def make_plant(config: PlantConfig | None = None, builder: DiagramBuilder | None = None, *, robot: Robot):
    """Add the finalized plant of `robot` and a SceneGraph to `builder`.

    Returns (plant, scene_graph). With builder=None a bare plant without SceneGraph is returned
    as (plant, None), for kinematics and dynamics queries. With `config.effects`: the viscous friction,
    rotor inertia and payload in the plant and, in a diagram (`builder`), the friction system driving the
    plant's applied generalized force and the actuators between a command and the plant's actuation
    (`effect_systems.add_effect_systems`; connect a command to `effect_systems.actuation_input(builder, plant)`);
    the mass scales are Context parameters (`config.set_parameters` on every context made of the diagram).
    """
    config = config or PlantConfig()
    if config.time_step < 0:
        raise ValueError(f"time_step must be >= 0, got {config.time_step}")
    if builder is None:
        plant = MultibodyPlant(config.time_step)
        scene_graph = None
    else:
        plant, scene_graph = AddMultibodyPlant(config.multibody, builder)
    instance = robot.add_to(plant)
    motors = add_effects_to_plant(plant, instance, robot, config.effects) if config.effects is not None else {}
    plant.Finalize()
    robot.check_plant(plant, instance)
    if builder is not None and config.effects is not None:
        add_effect_systems(builder, plant, instance, robot, config.effects, config.time_step, motors)
    if scene_graph is not None:
        if config.self_collision:
            _filter_disabled_collisions(plant, scene_graph, instance, robot)
        else:
            _filter_self_collisions(plant, scene_graph, instance)
    return plant, scene_graph


class PlantSimulator:
    """The plant diagram (plant + scene graph, actuation exported as the input port "actuation") and a
    Simulator, stepped by holding a torque: used by data collection and by the plant-as-model MPC.

    `start(x, tau)` resets every state variable to its default at t = 0, then sets the state x = [q, v]
    (2n,) and holds the action tau (m,) N m (one torque per actuated joint), so what follows depends only
    on its own inputs (the parameters are never changed)."""

    def __init__(self, plant_config: PlantConfig | None = None, *, robot: Robot):
        from pydrake.systems.analysis import Simulator

        builder = DiagramBuilder()
        plant_config = plant_config or PlantConfig()
        self.plant, _ = make_plant(plant_config, builder=builder, robot=robot)
        builder.ExportInput(actuation_input(builder, self.plant), "actuation")
        builder.ExportOutput(measured_state_output(builder, self.plant), "measured_state")
        self.diagram = builder.Build()
        self.simulator = Simulator(self.diagram)
        self.context = self.simulator.get_mutable_context()
        self.plant_context = self.plant.GetMyContextFromRoot(self.context)
        plant_config.set_parameters(self.plant, self.plant_context)
        self._actuation = self.diagram.GetInputPort("actuation")
        self._initial_state = self.diagram.CreateDefaultContext()  # what `start` resets the state to

    def get_actuation_input_port(self):
        """The diagram's input port "actuation": torques (m,) N m of the actuated joints."""
        return self._actuation

    def start(self, x: np.ndarray, tau: np.ndarray) -> None:
        """Reset to t = 0 with state x (2n,) and the action tau (m,) N m held. Every state variable
        (continuous, discrete, abstract) is reset to its default, the parameters are left as they are
        (nothing changes them): the same result as resetting the whole context, which costs tens of ms on
        a description with many collision meshes (its geometry is a parameter; 32 ms per step on
        tools/bench_plant_step.py's 6-mesh arm) against under 1 ms."""
        initial = self._initial_state
        self.context.get_mutable_continuous_state().SetFrom(initial.get_continuous_state())
        self.context.get_mutable_discrete_state().SetFrom(initial.get_discrete_state())
        self.context.get_mutable_abstract_state().SetFrom(initial.get_abstract_state())
        self.context.SetTime(0.0)
        self.plant.SetPositionsAndVelocities(self.plant_context, x)
        start_actuators(self.diagram, self.context, tau)   # (as if at rest holding tau before t = 0)
        self.hold(tau)
        self.simulator.Initialize()

    def hold(self, tau: np.ndarray) -> None:
        """Hold the action tau (m,) N m from now on."""
        self._actuation.FixValue(self.context, tau)

    def applied_torque(self) -> np.ndarray:
        """The torque (m,) N m the joints get now: the elastic transmissions' springs' or the actuators' output where
        the effects have them (lag, delay), else the held action."""
        return link_torque(self.diagram, self.plant, self.plant_context, self.context)

    def measured_state(self) -> np.ndarray:
        """The state [q, v] (2n,) a sensor reads now: the plant's, of `measurement_delay` earlier with that effect."""
        return self.diagram.GetOutputPort("measured_state").Eval(self.context)

    def advance_to(self, time: float) -> np.ndarray:
        """Simulate to `time` s and return the state [q, v] (2n,)."""
        self.simulator.AdvanceTo(time)
        return self.plant.GetPositionsAndVelocities(self.plant_context)


def _filter_self_collisions(plant, scene_graph, instance):
    """Exclude contact among all of the robot's collision geometries (the models nested in it too: a welded tool)."""
    geometry_ids = [geometry for model in (instance, *nested_instances(plant, instance)) for body in
                    plant.GetBodyIndices(model) for geometry in plant.GetCollisionGeometriesForBody(plant.get_body(body))]
    scene_graph.collision_filter_manager().Apply(
        CollisionFilterDeclaration().ExcludeWithin(GeometrySet(geometry_ids)))


def _filter_disabled_collisions(plant, scene_graph, instance, robot: Robot) -> None:
    """Exclude contact between the link pairs the robot's SRDF and config disable (`Robot.disabled_collisions`):
    for the simulation and for the self-collision check alike."""
    manager = scene_graph.collision_filter_manager()
    for first, second in robot.disabled_collisions(lambda link: plant.HasBodyNamed(link, instance)):
        geometries = [plant.GetCollisionGeometriesForBody(plant.GetBodyByName(link, instance)) for link in (first, second)]
        if all(geometries):
            manager.Apply(CollisionFilterDeclaration().ExcludeBetween(GeometrySet(geometries[0]),
                                                                      GeometrySet(geometries[1])))


@dataclasses.dataclass(frozen=True)
class JointLimits:
    """Limits read back from the plant: position rad and velocity rad/s (n,), effort N m of each actuated
    joint (m,)."""
    position_lower: np.ndarray
    position_upper: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray


def robot_joint_limits(robot: Robot) -> JointLimits:
    """The limits of `robot` as its plant states them (a bare plant built for the purpose)."""
    return joint_limits(make_plant(PlantConfig.continuous(), robot=robot)[0])


def joint_limits(plant: MultibodyPlant) -> JointLimits:
    return JointLimits(
        position_lower=plant.GetPositionLowerLimits().copy(),
        position_upper=plant.GetPositionUpperLimits().copy(),
        velocity=plant.GetVelocityUpperLimits().copy(),
        effort=plant.GetEffortUpperLimits().copy(),
    )


class Dynamics:
    """Continuous-time rigid-body dynamics of `robot` (a bare plant of its own), with `effects` those of
    an affected plant (None: the description, the nominal model).

    acceleration(q, v, tau) = M(q)^-1 (B tau + tau_g(q) - C(q, v) v - D v + tau_c(v)) for q, v (n,) and
    the action tau (m,) N m of the m actuated joints; B places each torque on its joint (B = I when
    m = n); D the joint damping (the description's plus viscous friction), tau_c the smoothed Coulomb
    friction; M includes reflected rotor inertia and the payload.
    """

    def __init__(self, robot: Robot, effects: PlantEffects | None = None):
        self.robot = robot
        self.effects = effects
        config = PlantConfig.discrete(0.0, effects=effects)
        self.plant, _ = make_plant(config, robot=self.robot)
        self.context = self.plant.CreateDefaultContext()
        config.set_parameters(self.plant, self.context)
        self._actuated = None if self.robot.fully_actuated else self.robot.actuated_indices
        self._damping = np.zeros(self.plant.num_velocities())   # D (n,) N m s/rad
        for index in self.plant.GetJointIndices():
            joint = self.plant.get_joint(index)
            start = joint.velocity_start()
            self._damping[start:start + joint.num_velocities()] = joint.default_damping_vector()
        self._coulomb = effects.coulomb(robot.num_joints) if effects is not None else None   # (F_c, v_s)
        self._stribeck = effects.stribeck(robot.num_joints) if effects is not None else None   # (F_s, v_st)
        self._ripple = effects.ripple(robot.num_joints) if effects is not None else None   # (r, P)

    @property
    def damping(self) -> np.ndarray:
        """The joint damping D (n,) N m s/rad (N s/m on a prismatic joint): the description's <dynamics
        damping>, plus the effects' viscous friction on an affected plant."""
        return self._damping

    def gravity_torque(self, q: np.ndarray) -> np.ndarray:
        """Torque (n,) N m on every joint that holds the arm still at q."""
        self.plant.SetPositions(self.context, q)
        return -self.plant.CalcGravityGeneralizedForces(self.context)

    def mass_matrix(self, q: np.ndarray) -> np.ndarray:
        """M(q) (n, n), kg m^2 (or kg for prismatic joints)."""
        self.plant.SetPositions(self.context, q)
        return self.plant.CalcMassMatrix(self.context)

    def effective_inertia(self, q: np.ndarray) -> np.ndarray:
        """Per joint (n,), the inertia it moves with the other joints free: 1 / (M(q)^-1)_ii."""
        return 1.0 / np.diag(np.linalg.inv(self.mass_matrix(q)))

    def actuated_gravity_torque(self, q: np.ndarray) -> np.ndarray:
        """The actuated joints' part (m,) N m of gravity_torque(q) (all of it for a fully actuated arm)."""
        torque = self.gravity_torque(q)
        return torque if self._actuated is None else torque[self._actuated]

    def generalized_force(self, tau: np.ndarray) -> np.ndarray:
        """The joint torques (n,) N m of an action tau (m,): zero on the unactuated joints."""
        if self._actuated is None:
            return tau
        force = np.zeros(self.robot.num_joints)
        force[self._actuated] = tau
        return force

    def damping_time_constants(self, q: np.ndarray | None = None) -> np.ndarray:
        """Per arm joint (n,), s: how fast its description's viscous <dynamics damping> d_i stops it
        alone, M_eff,i / d_i with M_eff = `effective_inertia` at q (default home); inf without damping."""
        q = self.robot.home if q is None else q
        damping = self._damping
        inertia = self.effective_inertia(q)
        with np.errstate(divide="ignore"):
            return np.where(damping > 0, inertia / np.where(damping > 0, damping, 1.0), np.inf)

    def acceleration(self, q: np.ndarray, v: np.ndarray, tau: np.ndarray) -> np.ndarray:
        plant, context = self.plant, self.context
        plant.SetPositionsAndVelocities(context, np.concatenate([q, v]))
        rhs = self.generalized_force(tau) + plant.CalcGravityGeneralizedForces(context) - plant.CalcBiasTerm(context)
        if self._damping.any():
            rhs = rhs - self._damping * v
        if self._coulomb is not None:
            rhs = rhs + coulomb_torque(v, *self._coulomb, self._stribeck, self._ripple, q)
        return np.linalg.solve(plant.CalcMassMatrix(context), rhs)


class SelfCollisionChecker:
    """Answers whether a configuration q (n,) of `robot` puts two of its links in contact: links that are
    not adjacent and whose pair the robot's SRDF or config does not disable. InputError when the robot's
    home is in self-collision (unless check_home is False)."""

    def __init__(self, robot: Robot, check_home: bool = True):
        builder = DiagramBuilder()
        self.plant, self.scene_graph = make_plant(PlantConfig.continuous(), builder=builder, robot=robot)
        self.diagram = builder.Build()
        self.context = self.diagram.CreateDefaultContext()
        self.plant_context = self.plant.GetMyContextFromRoot(self.context)
        touching = sorted({tuple(sorted(pair)) for pair in self.colliding_links(robot.home)}) if check_home else []
        if touching:
            listed = ", ".join(f"{a}/{b}" for a, b in touching[:4]) + (" ..." if len(touching) > 4 else "")
            raise InputError(f"robot {robot.name}: home is in self-collision ({listed}); choose another home, or "
                             "disable the pairs that touch by design (srdf: the MoveIt SRDF, or disabled_collisions)")

    def colliding_links(self, q: np.ndarray) -> list[tuple[str, str]]:
        self.plant.SetPositions(self.plant_context, q)
        query = self.plant.get_geometry_query_input_port().Eval(self.plant_context)
        inspector = query.inspector()
        body = lambda geometry_id: self.plant.GetBodyFromFrameId(inspector.GetFrameId(geometry_id)).name()
        return [(body(pair.id_A), body(pair.id_B)) for pair in query.ComputePointPairPenetration()]

    def is_collision_free(self, q: np.ndarray) -> bool:
        self.plant.SetPositions(self.plant_context, q)
        return not self.plant.get_geometry_query_input_port().Eval(self.plant_context).HasCollisions()
