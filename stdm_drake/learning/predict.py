"""Prediction with trained STDMs: one-step `predict`, open-loop `rollout`, and the fast inference path.

Both functions run on a network's inference engine (`TrainableModel.inference`; any kind gets
`trainable.TorchInference`); the ensemble MLP's is `InferenceModel`: a float32 numpy copy with the input
and output normalizers folded into the first and last layers, the first layer split into a state
part and an action part (the action part of a whole open-loop action sequence is one matmul before
the loop), and members stacked so an ensemble step is one batched matmul per layer. No autograd,
no nn.Module calls: a 100-step rollout costs well under a millisecond for a single 3x100 model.

Uncertainty propagation (PETS, Chua et al. 2018), `propagation=`:
  "mean"  every member predicts from the same state and the next state is the members' mean; the
          returned variance is the one-step predictive variance along that path (spread of the
          member means + mean aleatoric variance); `rollout` then equals repeated `predict`.
  "ts1"   `particles` particles per initial state; at every step each particle follows a member
          drawn uniformly at random and, for probabilistic models, samples its Gaussian.
  "tsinf" as ts1 but each particle keeps the member drawn at the start for the whole horizon.
For TS the mean and variance are over particles.

The NumPy activations and their slopes (for the Jacobians the MPC uses) are in
`stdm_drake.learning.activations`, beside each activation's torch passes.
"""
from __future__ import annotations


import numpy as np

from stdm_drake.errors import InputError
from stdm_drake.learning.activations import get_activation
from stdm_drake.dynamics.model import PROPAGATIONS, Prediction, Rollout
from stdm_drake.learning.trainable import input_rows, TrainableModel

MAX_PARTICLES = 10_000   # particles per trajectory (their states are held at once)


def _softplus(values):
    return np.logaddexp(values, 0.0)


def fold_input_standardization(weight: np.ndarray, bias: np.ndarray, mean: np.ndarray, std: np.ndarray):
    """A first layer (E, K, H), (E, 1, H) on standardized inputs as one on raw inputs, in float64:
    ((z - μ) / σ) W + b = z (W / σ) + (b - (μ / σ) W)."""
    return weight / std[None, :, None], bias - np.einsum("i,eio->eo", mean / std, weight)[:, None, :]


class InferenceModel:
    """Float32 numpy inference copy of an `models.EnsembleMLP` used as an STDM (see module docstring).

    A snapshot: build a new one after the network's weights change. Inputs are rows [x (S), a (A), 1]:
    the first layer (normalization, bias and the activation's input scale folded in) is one
    (S+A+1, E*H) matrix shared by all members. E members, H width.
    """

    def __init__(self, network):
        config = network.config
        self.config = config
        self.ensemble_size = config.ensemble_size
        self.state_dim = config.state_dim
        self.action_dim = config.action_dim
        self.residual = config.residual
        self.probabilistic = config.probabilistic
        activation = get_activation(config.activation)
        scale, self._activation, self._slope = activation.numpy_scale, activation.numpy, activation.numpy_slope

        def array(tensor):
            return tensor.detach().cpu().double().numpy()

        weights = [array(weight) for weight in network.weights]
        biases = [array(bias) for bias in network.biases]
        z_mean, z_std = array(network.input_normalizer.mean), array(network.input_normalizer.std)
        y_mean, y_std = array(network.output_normalizer.mean), array(network.output_normalizer.std)
        members, width = self.ensemble_size, weights[0].shape[2]
        first, first_bias = fold_input_standardization(weights[0], biases[0], z_mean, z_std)
        stacked = np.concatenate([first, first_bias], axis=1) * scale            # (E, S+A+1, H)
        f32 = np.float32
        self.input_weight = np.ascontiguousarray(stacked.transpose(1, 0, 2).reshape(-1, members * width), dtype=f32)
        self.input_member_weight = np.ascontiguousarray(stacked, dtype=f32)                     # (E, S+A+1, H)
        self.hidden = [(np.ascontiguousarray(w * scale, dtype=f32), np.ascontiguousarray(b * scale, dtype=f32))
                       for w, b in zip(weights[1:-1], biases[1:-1])]
        out = config.output_dim
        mean_weight = weights[-1][..., :out] * y_std
        mean_bias = biases[-1][..., :out] * y_std + y_mean
        self.mean_weight = np.ascontiguousarray(mean_weight, dtype=f32)                         # (E, H, S)
        self.mean_bias = np.ascontiguousarray(mean_bias, dtype=f32)                             # (E, 1, S)
        self.ensemble_mean_weight = np.ascontiguousarray(mean_weight.reshape(members * width, out) / members,
                                                         dtype=f32)                              # (E*H, S)
        self.ensemble_mean_bias = np.ascontiguousarray(mean_bias.mean(axis=0)[0], dtype=f32)    # (S,)
        self.width = width
        if self.probabilistic:
            self.logvar_weight = np.ascontiguousarray(weights[-1][..., out:], dtype=f32)
            self.logvar_bias = np.ascontiguousarray(biases[-1][..., out:], dtype=f32)
            self.min_logvar = array(network.min_logvar).astype(f32)
            self.max_logvar = array(network.max_logvar).astype(f32)
            self.log_output_variance = (2.0 * np.log(y_std)).astype(f32)

    def input_rows(self, states: np.ndarray, actions: np.ndarray) -> np.ndarray:
        """Rows [x, a, 1] for T steps (`trainable.input_rows`)."""
        return input_rows(states, actions, self.state_dim, self.action_dim)

    def workspace(self, count: int) -> "_Workspace":
        """Buffers for repeated steps on `count` input rows (no allocation inside a rollout loop)."""
        return _Workspace(self, count)

    def hidden_features(self, inputs: np.ndarray, workspace: "_Workspace", out: np.ndarray | None = None):
        """Last hidden layer (E, N, H) of every member for input rows (N, S+A+1).

        The result lives in `out` if given, else in the workspace (valid until its next use).
        """
        if workspace.first_members is not None:
            np.dot(inputs, self.input_weight, out=workspace.first)
            pre = workspace.first_members
        else:
            np.matmul(inputs, self.input_member_weight, out=workspace.pre)
            pre = workspace.pre
        activation, layers = self._activation, workspace.layers
        hidden = activation(pre, workspace.hidden if layers or out is None else out)
        if not layers:
            return hidden
        product, source, product_out = workspace.product, workspace.product_in, workspace.product_out
        pre = workspace.pre
        for weight, bias, final in layers:
            product(source, weight, out=product_out)
            pre += bias
            hidden = activation(pre, out if final and out is not None else workspace.hidden)
        return hidden

    def ensemble_mean(self, hidden: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """Mean over members of the network outputs (N, S) from hidden (E, N, H); residual not added."""
        members, count, width = hidden.shape
        return self.ensemble_mean_flat(hidden.transpose(1, 0, 2).reshape(count, members * width), out)

    def ensemble_mean_flat(self, flat: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        """As ensemble_mean, from hidden laid out member after member per row: (N, E*H)."""
        mean = np.dot(flat, self.ensemble_mean_weight, out=out)
        mean += self.ensemble_mean_bias
        return mean

    def mean_and_jacobian(self, inputs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The ensemble-mean network output (N, S) (residual not added: the caller adds the state in its own
        precision) and the Jacobian of the next state d/d[x, a] (N, S, S+A) (residual included) at input rows
        (N, S+A+1), float32, from one pass.

        Forward mode with all unit tangents at once: the tangents of every row and input are the rows of one
        (N (S+A), H) matrix per member, so each layer is one matrix product per member (not one per row).
        """
        width = self.state_dim + self.action_dim
        members, count = self.ensemble_size, len(inputs)
        pre = np.matmul(inputs, self.input_member_weight)                                # (E, N, H)
        tangent = self._slope(pre)[:, :, None, :] * self.input_member_weight[:, None, :width, :]   # (E, N, S+A, H)
        hidden = self._activation(pre, np.empty_like(pre))
        for weight, bias in self.hidden:                                                # weight (E, H, H)
            pre = np.matmul(hidden, weight)
            pre += bias
            tangent = np.matmul(tangent.reshape(members, count * width, -1), weight).reshape(tangent.shape)
            tangent *= self._slope(pre)[:, :, None, :]
            hidden = self._activation(pre, np.empty_like(pre))
        out = self.mean_weight.shape[-1]
        jacobian = np.matmul(tangent.reshape(members, count * width, -1), self.mean_weight)   # (E, N (S+A), S)
        jacobian = jacobian.mean(axis=0).reshape(count, width, out).transpose(0, 2, 1)       # (N, S, S+A)
        mean = (np.matmul(hidden, self.mean_weight) + self.mean_bias).mean(axis=0)              # (N, S)
        if self.residual:
            jacobian = jacobian + np.eye(out, width, dtype=np.float32)
        return mean, jacobian

    def member_block_outputs(self, inputs: np.ndarray):
        """Each member on its own rows: inputs (E, M, S+A+1), block e for member e -> (mean (E, M, S) raw units,
        residual not added; variance (E, M, S) or None). One batched product per layer, not E times the rows
        (the particles of PETS trajectory sampling, each following one member)."""
        pre = np.matmul(inputs, self.input_member_weight)
        hidden = self._activation(pre, np.empty_like(pre))
        for weight, bias in self.hidden:
            pre = np.matmul(hidden, weight)
            pre += bias
            hidden = self._activation(pre, hidden)
        return self.member_outputs(hidden)

    def member_outputs(self, hidden: np.ndarray):
        """Per-member outputs from hidden (E, M, H): (mean (E, M, S) raw units, residual not added;
        variance (E, M, S) or None)."""
        mean = np.matmul(hidden, self.mean_weight)
        mean += self.mean_bias
        if not self.probabilistic:
            return mean, None
        raw = np.matmul(hidden, self.logvar_weight)
        raw += self.logvar_bias
        upper = self.max_logvar - _softplus(self.max_logvar - raw)
        logvar = self.min_logvar + _softplus(upper - self.min_logvar)
        return mean, np.exp(logvar + self.log_output_variance)


class _Workspace:
    """Preallocated float32 buffers of one InferenceModel for N input rows."""

    def __init__(self, engine: InferenceModel, count: int):
        members, width = engine.ensemble_size, engine.width
        self.count = count
        self.pre = np.empty((members, count, width), dtype=np.float32)
        self.hidden = np.empty((members, count, width), dtype=np.float32)
        self.first = np.empty((count, members * width), dtype=np.float32)
        # one row: the (1, E*H) first-layer output is already laid out as (E, 1, H)
        self.first_members = self.first.reshape(members, 1, width) if count == 1 else None
        self.mean = np.empty((count, engine.state_dim), dtype=np.float32)
        # hidden layers: one member -> 2-D np.dot on views (cheaper than a batched matmul of one)
        single = members == 1
        self.product = np.dot if single else np.matmul
        self.product_in = self.hidden[0] if single else self.hidden
        self.product_out = self.pre[0] if single else self.pre
        self.layers = [(weight[0] if single else weight, bias, index == len(engine.hidden) - 1)
                       for index, (weight, bias) in enumerate(engine.hidden)]


def as_inference_model(model):
    """The inference engine of a network (`TrainableModel.inference`: extracted now), or the engine itself."""
    if isinstance(model, TrainableModel):
        return model.inference()
    if hasattr(model, "mean_and_jacobian") and hasattr(model, "hidden_features"):
        return model
    raise InputError(f"expected a trainable network or its inference engine, got {type(model).__name__}")


def _as_batch(values, width: int, name: str, *, sequence: bool) -> tuple[np.ndarray, bool]:
    """Validate and return float32 (B, [T,] width) and whether a batch axis was added."""
    array = np.asarray(values, dtype=np.float64)
    core = 2 if sequence else 1
    if array.ndim == core:
        array, added = array[None], True
    elif array.ndim == core + 1:
        added = False
    else:
        shape = "(B, T, A) or (T, A)" if sequence else "(B, S) or (S,)"
        raise InputError(f"{name} must have shape {shape}, got {array.shape}")
    if array.shape[-1] != width:
        raise InputError(f"{name} has {array.shape[-1]} columns, the model expects {width}")
    bad = int(np.count_nonzero(~np.isfinite(array)))
    if bad:
        raise InputError(f"{name} contains {bad} NaN or inf values")
    with np.errstate(over="ignore"):   # (beyond float32's range: inf, a diverged rollout's state)
        return array.astype(np.float32), added


def _predictive_variance(member_means: np.ndarray, member_variances: np.ndarray | None) -> np.ndarray:
    """Spread of the member means plus mean aleatoric variance: (E, M, S) -> (M, S)."""
    members = len(member_means)
    deviation = member_means - np.add.reduce(member_means, axis=0) / members
    variance = np.add.reduce(deviation * deviation, axis=0) / members
    if member_variances is not None:
        variance += np.add.reduce(member_variances, axis=0) / members
    return variance


def predict(model, states, actions=None) -> Prediction:
    """One-step prediction x_{t+1} for states (B, S) [q rad, v rad/s] and actions (B, A) (or unbatched).

    actions may be omitted for models without actions (A = 0).
    """
    engine = as_inference_model(model)
    x, added = _as_batch(states, engine.state_dim, "states", sequence=False)
    if actions is None:
        if engine.action_dim:
            raise InputError(f"actions are required: the model expects {engine.action_dim} action columns")
        actions = np.zeros((len(x), 0))
    a, _ = _as_batch(actions, engine.action_dim, "actions", sequence=False)
    if len(a) != len(x):
        raise InputError(f"states and actions have different batch sizes: {len(x)} and {len(a)}")
    inputs = engine.input_rows(x, a[None])[0]
    hidden = engine.hidden_features(inputs, engine.workspace(len(x)))
    mean = engine.ensemble_mean(hidden)
    member_means, member_variances = engine.member_outputs(hidden)
    variance = _predictive_variance(member_means, member_variances)   # (before the shared residual: no cancellation)
    if engine.residual:
        mean += x
        member_means += x
    if added:
        return Prediction(mean=mean[0], variance=variance[0], member_means=member_means[:, 0],
                          member_variances=None if member_variances is None else member_variances[:, 0])
    return Prediction(mean=mean, variance=variance, member_means=member_means, member_variances=member_variances)


def rollout(model, initial_states, actions, *, propagation: str = "mean", particles: int = 20,
            seed: int | None = 0, keep_particles: bool = False) -> Rollout:
    """Open-loop T-step prediction from initial_states (B, S) under actions (B, T, A) (or unbatched).

    Returns the predicted states of steps 1..T (not x_0). propagation: "mean", "ts1" or "tsinf"
    (module docstring); particles and seed apply to TS (seed None: fresh randomness). With "mean",
    rollout(x0, a)[t] equals predict applied t+1 times.
    """
    if propagation not in PROPAGATIONS:
        raise InputError(f"propagation must be one of {PROPAGATIONS}, got {propagation!r}")
    engine = as_inference_model(model)
    x0, added = _as_batch(initial_states, engine.state_dim, "initial_states", sequence=False)
    sequence, _ = _as_batch(actions, engine.action_dim, "actions", sequence=True)
    if len(sequence) != len(x0):
        if len(sequence) != 1:
            raise InputError(f"initial_states and actions have different batch sizes: {len(x0)} and {len(sequence)}")
        sequence = np.repeat(sequence, len(x0), axis=0)
    batch, horizon = sequence.shape[:2]
    members, size = engine.ensemble_size, engine.state_dim
    count = 1 if propagation == "mean" else int(particles)
    if not 1 <= count <= MAX_PARTICLES:
        raise InputError(f"particles must be in 1..{MAX_PARTICLES}, got {particles}")
    rows = batch * count
    inputs = engine.input_rows(np.repeat(x0, count, axis=0),
                               np.repeat(sequence, count, axis=0).transpose(1, 0, 2))   # (T+1, N, S+A+1)
    workspace = engine.workspace(rows)
    if propagation == "mean":
        keep = members > 1 or engine.probabilistic       # the variance needs every member's output
        hidden_steps = np.empty((horizon, members, rows, engine.width), dtype=np.float32) if keep else None
        mean_buffer = workspace.mean
        states = inputs[:, :, :size]
        # one row: step t's stored (E, 1, H) hidden is already the (1, E*H) row ensemble_mean_flat needs
        flat_steps = hidden_steps.reshape(horizon, 1, -1) if keep and rows == 1 else None
        for step in range(horizon):
            hidden = engine.hidden_features(inputs[step], workspace, out=hidden_steps[step] if keep else None)
            if flat_steps is not None:
                mean = engine.ensemble_mean_flat(flat_steps[step], out=mean_buffer)
            else:
                mean = engine.ensemble_mean(hidden, out=mean_buffer)
            if engine.residual:
                np.add(mean, states[step], out=states[step + 1])
            else:
                states[step + 1] = mean
        if keep:   # all steps at once: (T, E, N, H) -> (E, T*N, H)
            hidden_all = np.ascontiguousarray(hidden_steps.transpose(1, 0, 2, 3)).reshape(members, -1, engine.width)
            variance = _predictive_variance(*engine.member_outputs(hidden_all)).reshape(horizon, rows, size)
        else:
            variance = np.zeros((horizon, rows, size), dtype=np.float32)
        mean = np.ascontiguousarray(inputs[1:, :, :size].transpose(1, 0, 2))
        result = Rollout(mean=mean, variance=np.ascontiguousarray(variance.transpose(1, 0, 2)))
    else:
        rng = np.random.default_rng(seed)
        assigned = rng.integers(0, members, size=rows) if propagation == "tsinf" else None
        particle_index = np.arange(rows)
        for step in range(horizon):
            member_means, member_variances = engine.member_outputs(engine.hidden_features(inputs[step], workspace))
            chosen = assigned if propagation == "tsinf" else rng.integers(0, members, size=rows)
            following = member_means[chosen, particle_index]
            if member_variances is not None:
                following += np.sqrt(member_variances[chosen, particle_index]) * rng.standard_normal(
                    following.shape, dtype=np.float32)
            if engine.residual:
                following += inputs[step, :, :size]
            inputs[step + 1, :, :size] = following
        predicted = inputs[1:, :, :size].reshape(horizon, batch, count, size).transpose(1, 2, 0, 3)
        result = Rollout(mean=predicted.mean(axis=1), variance=predicted.var(axis=1),
                         particles=np.ascontiguousarray(predicted) if keep_particles else None)
    if added:
        result = Rollout(mean=result.mean[0], variance=result.variance[0],
                         particles=None if result.particles is None else result.particles[0])
    return result
