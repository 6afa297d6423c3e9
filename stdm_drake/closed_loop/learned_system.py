"""A trained STDM inside Drake: the `LearnedModel` adapter and the `LearnedDynamicsSystem` LeafSystem.

`LearnedModel` turns any checkpoint (D, P, DE, PE, with or without derivative training) into the
prediction-model interface the MPC uses: a batched `step` on the fast numpy inference path
(ensemble mean) and exact `jacobians` by forward mode on the same float32 path (the chain rule the
derivative loss trains), one batched call for the whole horizon.
"""
import numpy as np
from pydrake.systems.framework import LeafSystem

from stdm_drake.errors import InputError
from stdm_drake.learning.checkpoint import load_model
from stdm_drake.learning.predict import as_inference_model, predict
from stdm_drake.robot import UR10, Robot


class LearnedModel:
    """A checkpoint as a prediction model of `robot` (default: the UR-10 preset) with n joints, m of them
    actuated: step(x (N, 2n), u (N, m)), jacobians(x (H, 2n), u (H, m)).

    sample_period (s) comes from the checkpoint's metadata (the dataset it was trained on); a model
    of other state or action sizes than the robot's is refused.
    """

    def __init__(self, checkpoint_path, name: str | None = None, robot: Robot | None = None):
        robot = robot or UR10
        checkpoint = load_model(checkpoint_path, state_dim=robot.state_dim, action_dim=robot.action_dim)
        self.state_dim, self.action_dim = robot.state_dim, robot.action_dim
        self.checkpoint = checkpoint
        self.name = name or checkpoint.path.stem
        period = checkpoint.metadata.sample_period
        if period is None or not float(period) > 0:
            raise InputError(f"{checkpoint.path}: checkpoint metadata has no sample_period (train it on a dataset file)")
        self.sample_period = float(period)
        self.network = checkpoint.model.double()
        self.engine = as_inference_model(self.network)
        self.probabilistic = checkpoint.model_config.probabilistic
        self.ensemble_size = checkpoint.model_config.ensemble_size
        self._workspaces = {}

    def predict(self, x: np.ndarray, u: np.ndarray):
        """One-step Prediction (mean and variance (N, 12)); InputError on non-finite input."""
        return predict(self.engine, x, u)

    def step(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """Ensemble-mean next states (N, 12) for x (N, 12), u (N, 6); the MPC's hot path, so it
        skips `predict`'s input checks (the controller checks finiteness itself)."""
        engine = self.engine
        count = len(x)
        workspace = self._workspaces.get(count)
        if workspace is None:
            workspace = self._workspaces[count] = engine.workspace(count)
        rows = engine.input_rows(np.asarray(x, dtype=np.float32), np.asarray(u, dtype=np.float32)[None])[0]
        mean = engine.ensemble_mean(engine.hidden_features(rows, workspace)).astype(np.float64)
        if engine.residual:
            mean += x
        return mean

    def jacobians(self, x: np.ndarray, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """d mean / d(x, u) at each row: A (H, 12, 12), B (H, 12, 6), float64 from the float32
        inference path's forward-mode Jacobian (InferenceModel.mean_jacobian)."""
        rows = self.engine.input_rows(np.asarray(x, dtype=np.float32), np.asarray(u, dtype=np.float32)[None])[0]
        jacobian = self.engine.mean_jacobian(rows).astype(np.float64)
        return jacobian[:, :, :self.state_dim], jacobian[:, :, self.state_dim:]


class LearnedDynamicsSystem(LeafSystem):
    """Discrete-time Drake system that steps a learned STDM at its sample period.

    For a robot of n joints: input ports "torque" (n, N m), applied over [t_k, t_k+1);
    "measured_state" (2n, optional): when connected (or fixed), x_k is re-anchored to it before each
    step. State: the predicted [q (n) rad, v (n) rad/s]. Output ports: "state" (2n) and, for P/PE
    models, "variance" (2n): the one-step predictive variance of the last step (the same quantity
    as `rollout(..., propagation="mean")` returns).
    Non-finite torque or measurement inputs raise InputError.
    """

    def __init__(self, model: LearnedModel):
        super().__init__()
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
        """Input "torque": joint torques (6) N m applied over [t_k, t_k+1)."""
        return self.GetInputPort("torque")

    def get_measured_state_input_port(self):
        """Input "measured_state" (optional): [q, v] (2n) to re-anchor the prediction to before each step."""
        return self.GetInputPort("measured_state")

    def get_state_output_port(self):
        """Output "state": the predicted [q (6) rad, v (6) rad/s]."""
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
