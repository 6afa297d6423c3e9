"""How a network becomes a state-transition model: what it predicts and what it sees.

`ModelStructure(predicts, inputs)` for a robot with n joints and m actuated ones, x = [q, v]:

    predicts="state"     the network predicts the next state x_{t+1} (2n), as a delta x_t + f(z) or
                         directly (`--direct`): the paper's black box
    predicts="velocity"  the network predicts the next velocity v_{t+1} (n), as v_t + f(z) or directly,
                         and the next angle follows by the trapezoid rule
                         q̂_{t+1} = q_t + Δt (v_t + v̂_{t+1}) / 2, so the angle is never learned
    inputs="raw"         z = [q, v, τ]: the paper's inputs
    inputs="nominal_acceleration"
                         z also holds φ = M(q)⁻¹(B τ + τ_g(q) − C(q, v) v), the acceleration of the
                         robot's nominal rigid-body model (`physics.NominalAcceleration`): the torque
                         beyond gravity and bias, mapped through the inverse inertia
    inputs="period_acceleration"
                         z holds φ̄ instead: the nominal model's mean acceleration over the sample
                         period, linearized at (x, τ) (`physics.PeriodAcceleration`), so v + Δt φ̄ is
                         its next velocity; equal to φ up to O(Δt) on a UR-10, and the one that stays
                         meaningful on joints whose damping decays faster than the period (light
                         wrists of published descriptions with <dynamics damping>)
    inputs="plant_step"  the grey box: the network's delta adds to a plant model's next state x̂_{k+1}
                         (`plant_step.PlantStep`: the robot's description, or with `physics` the description
                         with an identified robot's parameters) instead of to x_k, and it sees [x̂ (or v̂),
                         x, τ]: it learns only what the plant model misses; ẋ̂ is the plant step's own
                         derivative along (ẋ, τ̇). The plant model steps by `plant_integrator`: "rk4" (what
                         `train` writes: exact Jacobians in microseconds) or "simulator" (the discrete
                         Drake plant; checkpoints written before the field existed)

The network's own input order puts the part its delta adds first: [x, τ, (φ)] for "state",
[v, q, τ, (φ)] for "velocity"; with plant-step inputs [x̂, x, τ] and [v̂, x, τ]. Derivative learning needs the time derivative of every input: ẋ and
Δτ/Δt from the dataset, φ̇ = ∂φ/∂(q, v, τ) (q̇, q̈, Δτ/Δt) by forward-mode AutoDiff through the plant.
For "velocity" the state loss is the velocity MSE and the derivative target q̈_{t+1}: the angle's
error is (Δt/2)² times the velocity's, so nothing is lost by leaving it out.

`PAPER` is the paper's structure (what `reproduce` compares); `DEFAULT` the most accurate one, what
`stdm-drake train` uses unless told otherwise.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from stdm_drake.errors import InputError
from stdm_drake.dynamics.physics import NominalAcceleration, PeriodAcceleration
from stdm_drake.dynamics.plant_step import PlantStep

PREDICTS = ("state", "velocity")
INPUT_SETS = ("raw", "nominal_acceleration", "period_acceleration", "plant_step")


@dataclasses.dataclass(frozen=True)
class ModelStructure:
    """What the network predicts ("state" or "velocity") and sees ("raw", "nominal_acceleration",
    "period_acceleration" or "plant_step"); physics: for plant-step inputs, the plant model's parameters
    when they are not the description's ({"effects": a PlantEffects record, "plant_time_step": s,
    "source": the identified robot's file}), None for the description."""
    predicts: str = "velocity"
    inputs: str = "nominal_acceleration"
    physics: dict | None = None
    plant_integrator: str | None = None    # plant-step inputs: the plant model's integrator; None: "simulator"

    def __post_init__(self):
        if self.predicts not in PREDICTS:
            raise InputError(f"model structure: predicts must be one of {PREDICTS}, got {self.predicts!r}")
        if self.inputs not in INPUT_SETS:
            raise InputError(f"model structure: inputs must be one of {INPUT_SETS}, got {self.inputs!r}")
        if self.physics is not None and (self.inputs != "plant_step" or not isinstance(self.physics, dict)
                                         or set(self.physics) != {"effects", "plant_time_step", "source"}):
            raise InputError("model structure: physics (effects, plant_time_step, source) belongs to plant-step "
                             f"inputs only, got {self.physics!r}")
        if self.plant_integrator is not None and (self.inputs != "plant_step"
                                                  or self.plant_integrator not in ("rk4", "simulator")):
            raise InputError("model structure: plant_integrator ('rk4' or 'simulator') belongs to plant-step inputs "
                             f"only, got {self.plant_integrator!r}")

    def __hash__(self):
        return hash((self.predicts, self.inputs, repr(self.physics), self.plant_integrator))

    @classmethod
    def from_dict(cls, values: dict | None) -> "ModelStructure":
        """From checkpoint metadata; None (checkpoints written before structures existed) is the paper's."""
        if values is None:
            return PAPER
        if not isinstance(values, dict) or set(values) - {"predicts", "inputs", "physics", "plant_integrator"}:
            raise InputError(f"model structure: expected keys predicts, inputs (and physics, plant_integrator), got "
                             f"{values!r}")
        return cls(**values)

    def as_dict(self) -> dict:
        values = dataclasses.asdict(self)
        for key in ("physics", "plant_integrator"):   # (the record of structures without them stays as it was)
            if values[key] is None:
                del values[key]
        return values

    @property
    def uses_nominal_model(self) -> bool:
        return self.inputs != "raw"

    def nominal_features(self, robot, sample_period: float):
        """The nominal-model input of this structure for `robot` at `sample_period` s (None for raw
        inputs): a `NominalAcceleration`, a `PeriodAcceleration` or a `PlantStep`."""
        if self.inputs == "raw":
            return None
        if self.inputs == "period_acceleration":
            return PeriodAcceleration(robot, sample_period)
        if self.inputs == "plant_step":
            integrator = self.plant_integrator or "simulator"
            if self.physics is None:
                return PlantStep(robot, sample_period, integrator=integrator)
            from stdm_drake.robots.effects import PlantEffects   # lazy: pydrake
            return PlantStep(robot, sample_period, PlantEffects.from_record(self.physics["effects"]),
                             self.physics["plant_time_step"], integrator=integrator)
        return NominalAcceleration(robot)

    @property
    def grey_box(self) -> bool:
        """Whether the network's delta adds to a plant model's next state (plant-step inputs)."""
        return self.inputs == "plant_step"

    @property
    def label(self) -> str:
        """Short description for tables: e.g. "velocity + trapezoid, nominal-acceleration inputs"."""
        what = "next state" if self.predicts == "state" else "next velocity, q by trapezoid"
        seen = {"raw": "raw inputs", "nominal_acceleration": "nominal-acceleration inputs",
                "period_acceleration": "period-acceleration inputs",
                "plant_step": "grey box on the " + ("identified" if self.physics else "description's") + " plant step"
                }[self.inputs]
        return f"{what}, {seen}"

    def network_sizes(self, state_dim: int, action_dim: int) -> tuple[int, int]:
        """(input_dim, output_dim) of the network for a state of state_dim = 2n and action_dim = m."""
        joints = state_dim // 2
        output = state_dim if self.predicts == "state" else joints
        if self.grey_box:     # [x̂ or v̂, x, τ]
            return output + state_dim + action_dim, output
        extra = joints if self.uses_nominal_model else 0
        return state_dim + action_dim + extra, output

    def model_sizes(self, input_dim: int, output_dim: int) -> tuple[int, int]:
        """(state_dim, action_dim) of the model a network of these sizes serves (network_sizes inverted)."""
        joints = output_dim // 2 if self.predicts == "state" else output_dim
        extra = output_dim if self.grey_box else joints if self.uses_nominal_model else 0
        action = input_dim - 2 * joints - extra
        if action < 0 or (self.predicts == "state" and output_dim % 2):
            raise InputError(f"a network of {input_dim} inputs and {output_dim} outputs does not fit the structure "
                             f"{self.label}")
        return 2 * joints, action

    def split(self, x: np.ndarray, a: np.ndarray, features: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """The network's (state part, rest) of its input rows for x (N, 2n), a (N, m), φ (N, n) or None
        (plant-step inputs: x̂ (N, 2n)): the state part is what its delta adds to (x or v; x̂ or v̂)."""
        joints = x.shape[1] // 2
        if self.grey_box:
            return (features if self.predicts == "state" else features[:, joints:]), np.hstack([x, a])
        extra = [] if features is None else [features]
        if self.predicts == "state":
            return x, np.hstack([a] + extra)
        return x[:, joints:], np.hstack([x[:, :joints], a] + extra)

    def regression_data(self, transitions, features=None, *, rates: bool = True):
        """Training pairs (`RegressionData`) of dataset `Transitions` in the network's layout; `features`
        (a `NominalAcceleration`) is needed for nominal-acceleration inputs; rates=False leaves out the
        derivative tangents and targets (validation data)."""
        from stdm_drake.learning.regression import RegressionData   # lazy: torch
        x, a = np.asarray(transitions.state, dtype=np.float64), np.asarray(transitions.action, dtype=np.float64)
        joints = x.shape[1] // 2
        q, v = x[:, :joints], x[:, joints:]
        x_rate = np.asarray(transitions.state_rate, dtype=np.float64)
        a_rate = np.asarray(transitions.action_rate, dtype=np.float64)
        phi = phi_rate = None
        if self.uses_nominal_model:
            if features is None:
                raise InputError("nominal-acceleration inputs need the robot's nominal model")
            phi = features.values(q, v, a)
            if rates:
                phi_rate = features.rates(q, v, a, x_rate[:, :joints], x_rate[:, joints:], a_rate)
        state, rest = self.split(x, a, phi)
        state_rate, rest_rate = self.split(x_rate, a_rate, phi_rate) if rates else (None, None)
        next_state, next_rate = np.asarray(transitions.next_state), np.asarray(transitions.next_state_rate)
        if self.predicts == "velocity":
            next_state, next_rate = next_state[:, joints:], next_rate[:, joints:]
        return RegressionData(inputs=np.hstack([state, rest]), targets=next_state,
                              input_rates=np.hstack([state_rate, rest_rate]) if rates else None,
                              target_rates=next_rate if rates else None,
                              groups=np.asarray(transitions.trajectory, dtype=int))


PAPER = ModelStructure(predicts="state", inputs="raw")
DEFAULT = ModelStructure()
