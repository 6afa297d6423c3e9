"""A push on the arm during a closed loop (a person or an obstacle pushing it): generalized forces on the arm joints
for a while, fed into the plant's applied generalized force beside the actuators, so the effort limits do not bound
them (`mpc.build_closed_loop(push=...)`; the constrained-MPC study's push scenario)."""
import dataclasses

import numpy as np
from pydrake.systems.framework import DiagramBuilder, LeafSystem

from stdm_drake.robots.robot import Robot


@dataclasses.dataclass(frozen=True)
class JointPush:
    """A push on the arm during a closed loop: generalized forces `torque` (n,) N m on the arm joints (the robot's
    joint order) from `start` s for `duration` s, added to the plant's applied generalized force: beside the
    actuators, so the effort limits do not bound it (a person or an obstacle pushing the arm)."""
    torque: np.ndarray
    start: float
    duration: float


class PushSource(LeafSystem):
    """Output "generalized_force" (the plant's velocities): a `JointPush`'s torques on its joints (`indices`, their
    velocity indices in the plant) while it lasts, zero before and after."""

    def __init__(self, push: JointPush, indices, size: int):
        super().__init__()
        self._push = push
        self._force = np.zeros(size)
        self._force[np.asarray(indices)] = np.asarray(push.torque, dtype=float)
        self.DeclareVectorOutputPort("generalized_force", size, self._output)

    def _output(self, context, output):
        t, push = context.get_time(), self._push
        output.SetFromVector(self._force if push.start <= t < push.start + push.duration else 0.0 * self._force)


def add_push(builder: DiagramBuilder, plant, robot: Robot, push: JointPush) -> None:
    """Feed `push` into the plant's applied generalized force, summed with what already drives that input (the
    plant effects' Coulomb friction)."""
    from pydrake.systems.primitives import Adder
    size = plant.num_velocities()
    indices = [plant.GetJointByName(name).velocity_start() for name in robot.joint_names]
    source = builder.AddSystem(PushSource(push, indices, size))
    source.set_name("push")
    target = plant.get_applied_generalized_force_input_port()
    driving = next((output for (system, index), output in builder.connection_map().items()
                    if system is plant and index == target.get_index()), None)
    if driving is None:
        builder.Connect(source.get_output_port(), target)
        return
    driving_port = driving[0].get_output_port(driving[1])
    builder.Disconnect(driving_port, target)
    total = builder.AddSystem(Adder(2, size))
    total.set_name("applied_generalized_force")
    builder.Connect(driving_port, total.get_input_port(0))
    builder.Connect(source.get_output_port(), total.get_input_port(1))
    builder.Connect(total.get_output_port(), target)
