"""A state-transition model inside Drake: the `LearnedDynamicsSystem` LeafSystem steps any
`DynamicsModel` (a trained checkpoint as `LearnedModel`, a physics baseline, the plant itself)."""
import numpy as np
from pydrake.systems.framework import LeafSystem

from stdm_drake.errors import InputError
from stdm_drake.dynamics.model import DynamicsModel


class LearnedDynamicsSystem(LeafSystem):
    """Discrete-time Drake system that steps a DynamicsModel (with a sample period) at that period.

    For a robot of n joints: input ports "torque" (n, N m), applied over [t_k, t_k+1);
    "measured_state" (2n, optional): when connected (or fixed), x_k is re-anchored to it before each
    step. State: the predicted [q (n) rad, v (n) rad/s]. Output ports: "state" (2n) and, for P/PE
    models, "variance" (2n): the one-step predictive variance of the last step (the same quantity
    as `rollout(..., propagation="mean")` returns).
    Non-finite torque or measurement inputs raise InputError.
    """

    def __init__(self, model: DynamicsModel):
        super().__init__()
        if not isinstance(model, DynamicsModel) or not model.sample_period:
            raise InputError("LearnedDynamicsSystem needs a DynamicsModel with a sample period")
        self.model = model
        n = self.state_dim = model.state_dim
        self._torque = self.DeclareVectorInputPort("torque", model.action_dim)
        self._measured = self.DeclareVectorInputPort("measured_state", n)
        self._state_index = self.DeclareDiscreteState(n)
        self._variance_index = self.DeclareDiscreteState(n)
        self.DeclareStateOutputPort("state", self._state_index)
        if model.probabilistic or model.ensemble_size > 1:
            self.DeclareStateOutputPort("variance", self._variance_index)
        self.DeclarePeriodicDiscreteUpdateEvent(model.sample_period, 0.0, self._step)

    def get_torque_input_port(self):
        """Input "torque": joint torques (m) N m applied over [t_k, t_k+1)."""
        return self.GetInputPort("torque")

    def get_measured_state_input_port(self):
        """Input "measured_state" (optional): [q, v] (2n) to re-anchor the prediction to before each step."""
        return self.GetInputPort("measured_state")

    def get_state_output_port(self):
        """Output "state": the predicted [q (n) rad, v (n) rad/s]."""
        return self.GetOutputPort("state")

    def get_variance_output_port(self):
        """Output "variance" (P/PE models and ensembles only): the one-step predictive variance (2n)."""
        return self.GetOutputPort("variance")

    def set_initial_state(self, context, x0: np.ndarray) -> None:
        """x0: (2n,) [q rad, v rad/s] in this system's context."""
        x0 = np.asarray(x0, dtype=float)
        if x0.shape != (self.state_dim,) or not np.all(np.isfinite(x0)):
            raise InputError(f"initial state must be {self.state_dim} finite numbers, got shape {x0.shape}")
        context.SetDiscreteState(int(self._state_index), x0)
        context.SetDiscreteState(int(self._variance_index), np.zeros(self.state_dim))

    def _step(self, context, discrete_state):
        torque = np.asarray(self._torque.Eval(context))
        if not np.all(np.isfinite(torque)):
            raise InputError(f"{self.get_name()}: non-finite torque input at t = {context.get_time():.4f} s")
        x = context.get_discrete_state(int(self._state_index)).get_value()
        if self._measured.HasValue(context):
            x = np.asarray(self._measured.Eval(context))
            if not np.all(np.isfinite(x)):
                raise InputError(f"{self.get_name()}: non-finite measured_state at t = {context.get_time():.4f} s")
        prediction = self.model.predict(x, torque)
        discrete_state.get_mutable_vector(int(self._state_index)).SetFromVector(prediction.mean.astype(float))
        discrete_state.get_mutable_vector(int(self._variance_index)).SetFromVector(prediction.variance.astype(float))
