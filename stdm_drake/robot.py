"""The UR-10 in Drake: model paths, limits, and the plant + scene-graph diagram builder.

Joint order everywhere in stdm-drake: shoulder_pan, shoulder_lift, elbow, wrist_1, wrist_2,
wrist_3. State x = [q (6) rad, v (6) rad/s]; action = joint torque (6) N m.
"""

import dataclasses
import hashlib
import os
import pathlib

import numpy as np

os.environ.setdefault("DRAKE_ALLOW_NETWORK", "meshcat")

from pydrake.geometry import CollisionFilterDeclaration, GeometrySet  # noqa: E402
from pydrake.math import RigidTransform  # noqa: E402
from pydrake.multibody.parsing import Parser  # noqa: E402
from pydrake.multibody.plant import AddMultibodyPlant, MultibodyPlant, MultibodyPlantConfig  # noqa: E402
from pydrake.systems.framework import DiagramBuilder  # noqa: E402

from stdm_drake.paths import MODELS_DIR  # noqa: E402

UR10_URDF = MODELS_DIR / "ur10.urdf"

JOINT_NAMES = (
    "shoulder_pan_joint", "shoulder_lift_joint", "elbow_joint",
    "wrist_1_joint", "wrist_2_joint", "wrist_3_joint",
)
NUM_JOINTS = 6
STATE_DIM = 2 * NUM_JOINTS  # x = [q, v]
TOOL_FRAME = "tool0"
BASE_FRAME = "base_link_inertia"


@dataclasses.dataclass
class PlantConfig:
    """How the UR-10 plant is simulated.

    time_step: discrete plant step (s); 0 gives a continuous-time plant.
    discrete_contact_approximation: Drake's discrete solver ("tamsi", "sap", "lagged", "similar").
    self_collision: keep contact between the robot's own (non-adjacent) links.
    """
    time_step: float = 0.001
    discrete_contact_approximation: str = "sap"
    self_collision: bool = True


def model_sha256(path: pathlib.Path = UR10_URDF) -> str:
    """SHA-256 of the robot description file, stored in every dataset and checkpoint."""
    return hashlib.sha256(pathlib.Path(path).read_bytes()).hexdigest()


def offline_parser(plant: MultibodyPlant, model_name_prefix: str = "") -> Parser:
    """A Parser whose package map holds no remote packages.

    Drake's default PackageMap registers the remote `drake_models` package, and with
    DRAKE_ALLOW_NETWORK=meshcat that registration itself throws. We construct the parser with
    the variable briefly unset, then drop `drake_models`, so that any package://drake_models
    reference fails at once ("unknown package") instead of trying a download.
    """
    saved = os.environ.pop("DRAKE_ALLOW_NETWORK", None)
    try:
        parser = Parser(plant, model_name_prefix=model_name_prefix)
    finally:
        if saved is not None:
            os.environ["DRAKE_ALLOW_NETWORK"] = saved
    if parser.package_map().Contains("drake_models"):
        parser.package_map().Remove("drake_models")
    return parser


def add_ur10(plant: MultibodyPlant, urdf: pathlib.Path = UR10_URDF, model_name_prefix: str = ""):
    """Parse the UR-10 into `plant`, weld base_link to the world, return the model instance.

    model_name_prefix: scopes the instance's name ("ghost" gives "ghost::ur10"), so that several
    UR-10s can share a plant (e.g. for visualization).
    """
    if not pathlib.Path(urdf).is_file():
        raise FileNotFoundError(f"robot description not found: {urdf}")
    (instance,) = offline_parser(plant, model_name_prefix).AddModels(str(urdf))
    plant.WeldFrames(plant.world_frame(), plant.GetFrameByName("base_link", instance), RigidTransform())
    return instance


def make_plant(config: PlantConfig | None = None, builder: DiagramBuilder | None = None):
    """Add the finalized UR-10 plant (and a SceneGraph) to `builder`.

    Returns (plant, scene_graph). With builder=None a bare plant without SceneGraph is returned
    as (plant, None), for kinematics and dynamics queries.
    """
    config = config or PlantConfig()
    if config.time_step < 0:
        raise ValueError(f"time_step must be >= 0, got {config.time_step}")
    if builder is None:
        plant = MultibodyPlant(config.time_step)
        scene_graph = None
    else:
        plant_config = MultibodyPlantConfig(
            time_step=config.time_step,
            discrete_contact_approximation=config.discrete_contact_approximation)
        plant, scene_graph = AddMultibodyPlant(plant_config, builder)
    add_ur10(plant)
    plant.Finalize()
    if scene_graph is not None and not config.self_collision:
        _filter_self_collisions(plant, scene_graph)
    return plant, scene_graph


class PlantSimulator:
    """The plant diagram (plant + scene graph, actuation exported as the input port "actuation") and a
    Simulator, stepped by holding a torque: used by data collection and by the plant-as-model MPC.

    `start(x, tau)` resets to a fresh default context at t = 0 with state x = [q, v] (12,) and the held
    torque tau (6,) N m, so what follows depends only on its own inputs."""

    def __init__(self, plant_config: PlantConfig | None = None):
        from pydrake.systems.analysis import Simulator

        builder = DiagramBuilder()
        self.plant, _ = make_plant(plant_config or PlantConfig(), builder=builder)
        builder.ExportInput(self.plant.get_actuation_input_port(), "actuation")
        self.diagram = builder.Build()
        self.simulator = Simulator(self.diagram)
        self.context = self.simulator.get_mutable_context()
        self.plant_context = self.plant.GetMyContextFromRoot(self.context)

    def get_actuation_input_port(self):
        """The diagram's input port "actuation": joint torques (6,) N m."""
        return self.diagram.GetInputPort("actuation")

    def start(self, x: np.ndarray, tau: np.ndarray) -> None:
        """Reset to t = 0 with state x (12,) and torque tau (6,) N m held."""
        self.diagram.SetDefaultContext(self.context)
        self.context.SetTime(0.0)
        self.plant.SetPositionsAndVelocities(self.plant_context, x)
        self.hold(tau)
        self.simulator.Initialize()

    def hold(self, tau: np.ndarray) -> None:
        """Hold the joint torques tau (6,) N m from now on."""
        self.get_actuation_input_port().FixValue(self.context, tau)

    def advance_to(self, time: float) -> np.ndarray:
        """Simulate to `time` s and return the state [q, v] (12,)."""
        self.simulator.AdvanceTo(time)
        return self.plant.GetPositionsAndVelocities(self.plant_context)


def _filter_self_collisions(plant, scene_graph):
    """Exclude contact among all of the robot's collision geometries."""
    geometry_ids = []
    for body_index in plant.GetBodyIndices(plant.GetModelInstanceByName("ur10")):
        geometry_ids.extend(plant.GetCollisionGeometriesForBody(plant.get_body(body_index)))
    scene_graph.collision_filter_manager().Apply(
        CollisionFilterDeclaration().ExcludeWithin(GeometrySet(geometry_ids)))


@dataclasses.dataclass(frozen=True)
class JointLimits:
    """Limits read back from the plant, each (6,): position rad, velocity rad/s, effort N m."""
    position_lower: np.ndarray
    position_upper: np.ndarray
    velocity: np.ndarray
    effort: np.ndarray


def joint_limits(plant: MultibodyPlant) -> JointLimits:
    return JointLimits(
        position_lower=plant.GetPositionLowerLimits().copy(),
        position_upper=plant.GetPositionUpperLimits().copy(),
        velocity=plant.GetVelocityUpperLimits().copy(),
        effort=plant.GetEffortUpperLimits().copy(),
    )


class Dynamics:
    """Continuous-time rigid-body dynamics of the UR-10 (a bare plant of its own).

    acceleration(q, v, tau) = M(q)^-1 (tau + tau_g(q) - C(q, v) v), all (6,) arrays.
    """

    def __init__(self):
        self.plant, _ = make_plant(PlantConfig(time_step=0.0))
        self.context = self.plant.CreateDefaultContext()

    def gravity_torque(self, q: np.ndarray) -> np.ndarray:
        """Torque (6,) N m that holds the arm still at q."""
        self.plant.SetPositions(self.context, q)
        return -self.plant.CalcGravityGeneralizedForces(self.context)

    def acceleration(self, q: np.ndarray, v: np.ndarray, tau: np.ndarray) -> np.ndarray:
        plant, context = self.plant, self.context
        plant.SetPositionsAndVelocities(context, np.concatenate([q, v]))
        rhs = tau + plant.CalcGravityGeneralizedForces(context) - plant.CalcBiasTerm(context)
        return np.linalg.solve(plant.CalcMassMatrix(context), rhs)


class SelfCollisionChecker:
    """Answers whether a configuration q (6,) rad puts two non-adjacent links in contact."""

    def __init__(self):
        builder = DiagramBuilder()
        self.plant, self.scene_graph = make_plant(PlantConfig(time_step=0.0), builder=builder)
        self.diagram = builder.Build()
        self.context = self.diagram.CreateDefaultContext()
        self.plant_context = self.plant.GetMyContextFromRoot(self.context)

    def colliding_links(self, q: np.ndarray) -> list[tuple[str, str]]:
        self.plant.SetPositions(self.plant_context, q)
        query = self.plant.get_geometry_query_input_port().Eval(self.plant_context)
        inspector = query.inspector()
        body = lambda geometry_id: self.plant.GetBodyFromFrameId(inspector.GetFrameId(geometry_id)).name()
        return [(body(pair.id_A), body(pair.id_B)) for pair in query.ComputePointPairPenetration()]

    def is_collision_free(self, q: np.ndarray) -> bool:
        self.plant.SetPositions(self.plant_context, q)
        return not self.plant.get_geometry_query_input_port().Eval(self.plant_context).HasCollisions()
