"""A trained network as a `DynamicsModel`: `LearnedModel` wraps a checkpoint (or a bare network) and its
`ModelStructure`, so every command treats the paper's black boxes and the physics-structured networks
alike.

The network runs on its float32 inference engine (`TrainableModel.inference`: the MLP's `predict.InferenceModel`,
any other kind's `trainable.TorchInference`); nominal-acceleration
inputs are evaluated by the robot's rigid-body model at every step (`robots.rigid_body`, built from the
Drake plant), and their analytic Jacobian enters the model's Jacobian by the chain rule.
"""
from __future__ import annotations

import pathlib

import numpy as np

from stdm_drake.errors import InputError
from stdm_drake.dynamics.model import DynamicsModel, Prediction, Rollout, check_batch
from stdm_drake.dynamics.compiled_core import IMPLEMENTATIONS, compiled_model, compiled_rollout
from stdm_drake.learning.predict import as_inference_model, predict, rollout
from stdm_drake.learning.structure import PAPER, ModelStructure
from stdm_drake.learning.particles import TorchParticles
from stdm_drake.learning.models import parse_model_type


class LearnedModel(DynamicsModel):
    """A checkpoint (path or loaded `Checkpoint`) or a bare network (a `TrainableModel` or its engine, then
    with `structure`, default the paper's) as a model of `robot` with n joints and m actuated ones.

    sample_period (s): a checkpoint's own (`Checkpoint.sample_period`: one without it is refused), a bare
    network's the `sample_period` given (None: none). A model of other sizes than the robot's, or one
    trained on another robot's description, is refused. The robot is also the nominal model of
    nominal-acceleration inputs; a checkpoint needs it, unless check_robot=False takes the checkpoint
    (raw inputs only) as it is.
    """
    learned = True

    def __init__(self, source, name: str | None = None, robot=None, *, structure: ModelStructure | None = None,
                 sample_period: float | None = None, check_robot: bool = True):
        from stdm_drake.learning.checkpoint import Checkpoint, load_checkpoint   # lazy: pydrake, h5py
        self.checkpoint = None
        if not isinstance(source, (str, pathlib.Path, Checkpoint)):   # a bare network or its engine
            self.structure = structure or PAPER
            network, self.name, self.sample_period = source, name or "network", sample_period
        else:
            checkpoint = source if isinstance(source, Checkpoint) else load_checkpoint(pathlib.Path(source))
            self.checkpoint = checkpoint
            self.structure = checkpoint.structure
            network = checkpoint.model.double()
            self.name = name or checkpoint.path.stem
            self.sample_period = checkpoint.sample_period
        self.network = network
        self.engine = as_inference_model(network)
        config = self.engine.config
        self.state_dim, self.action_dim = self.structure.model_sizes(config.input_dim, config.output_dim)
        self.probabilistic, self.ensemble_size = config.probabilistic, config.ensemble_size
        if self.structure.predicts == "velocity" and self.sample_period is None:
            raise InputError("a velocity-structured model needs its sample period (the trapezoid step)")
        if robot is None and self.checkpoint is not None and check_robot:
            raise InputError(f"{self.checkpoint.path}: pass the robot the model was trained on")
        self.robot = robot
        if robot is not None:
            self._check_robot(robot)
        self.features = None
        if self.structure.uses_nominal_model:
            if robot is None:
                raise InputError(f"{self.name}: inputs {self.structure.inputs!r} need the robot's nominal model")
            self.features = self.structure.nominal_features(self.robot, self.sample_period)
        self._workspaces = {}
        self._row = None    # (input order, input row, workspace) of `step_single`, made on first use

    def _check_robot(self, robot) -> None:
        where = self.checkpoint.path if self.checkpoint is not None else self.name
        if (self.state_dim, self.action_dim) != (robot.state_dim, robot.action_dim):
            raise InputError(f"{where}: model has state dim {self.state_dim} and action dim {self.action_dim}, "
                             f"expected state dim {robot.state_dim} and action dim {robot.action_dim} "
                             f"(robot {robot.name})")
        recorded = self.checkpoint.metadata.robot_model_sha256 if self.checkpoint is not None else None
        if recorded is not None and recorded != robot.model_sha256():
            raise InputError(f"{where}: trained on another robot description than {robot.model_path.name} "
                             f"(robot {robot.name}); pass its config with --robot")

    # -- the network's view of a step ------------------------------------------------------------------

    def _network_rows(self, x: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        features = None
        if self.features is not None:   # a diverged rollout state gets NaN features (Drake refuses it)
            n, finite = self.num_joints, np.isfinite(x).all(axis=1) & np.isfinite(a).all(axis=1)
            features = np.full((len(x), self.features.width), np.nan)
            if finite.any():
                features[finite] = self.features.values(x[finite, :n], x[finite, n:], a[finite])
        return self.structure.split(x, a, features)

    def _assemble(self, x: np.ndarray, network_mean: np.ndarray) -> np.ndarray:
        """The model's next state (N, 2n) from the network's mean output (residual added)."""
        if self.structure.predicts == "state":
            return network_mean
        n, dt = self.num_joints, self.sample_period
        return np.hstack([x[:, :n] + 0.5 * dt * (x[:, n:] + network_mean), network_mean])

    def _assemble_variance(self, variance: np.ndarray) -> np.ndarray:
        if self.structure.predicts == "state":
            return variance
        return np.hstack([(0.5 * self.sample_period) ** 2 * variance, variance])

    def step(self, x: np.ndarray, a: np.ndarray) -> np.ndarray:
        """Ensemble-mean next states (N, 2n) for x (N, 2n), a (N, m); the MPC's hot path, so it skips
        `predict`'s input checks (the controller checks finiteness itself)."""
        x, a = np.asarray(x, dtype=np.float64), np.asarray(a, dtype=np.float64)
        if len(x) == 1 and not self.structure.grey_box:
            return self.step_single(x[0], a[0])[None]
        state, rest = self._network_rows(x, a)
        engine = self.engine
        workspace = self._workspaces.get(len(x))
        if workspace is None:
            workspace = self._workspaces[len(x)] = engine.workspace(len(x))
        rows = engine.input_rows(state.astype(np.float32), rest.astype(np.float32)[None])[0]
        mean = engine.ensemble_mean(engine.hidden_features(rows, workspace)).astype(np.float64)
        if engine.residual:
            mean += state
        return self._assemble(x, mean)

    def step_single(self, x: np.ndarray, a: np.ndarray) -> np.ndarray:
        """`step` of one row x (2n,), a (m,) on 1-D arrays, the same float32 operations as the batch (the
        MPC's sequential rollouts: a few numpy calls per step)."""
        if self.structure.grey_box:
            return super().step_single(x, a)
        n, engine = self.num_joints, self.engine
        if self._row is None:
            order = np.arange(self.state_dim + self.action_dim + (0 if self.features is None else self.features.width))
            if self.structure.predicts == "velocity":                # network inputs [v, q, τ, (φ)]
                order[:2 * n] = np.concatenate([order[n:2 * n], order[:n]])
            self._row = (order, engine.input_rows(np.zeros((1, engine.state_dim), np.float32),
                                                  np.zeros((1, 1, engine.action_dim), np.float32))[0],
                         engine.workspace(1))
        order, row, workspace = self._row
        if self.features is None:
            z = np.concatenate([x, a])
        elif np.isfinite(x).all() and np.isfinite(a).all():
            z = np.concatenate([x, a, self.features.value_row(x[:n], x[n:], a)])
        else:                                                       # a diverged rollout state: NaN features
            z = np.concatenate([x, a, np.full(self.features.width, np.nan)])
        row[0, :-1] = z[order]
        mean = engine.ensemble_mean(engine.hidden_features(row, workspace))[0].astype(np.float64)
        if self.structure.predicts == "state":
            return mean + x if engine.residual else mean
        if engine.residual:
            mean += x[n:]
        return np.concatenate([x[:n] + 0.5 * self.sample_period * (x[n:] + mean), mean])

    def member_step(self, x: np.ndarray, a: np.ndarray, rng: np.random.Generator | None = None) -> np.ndarray:
        """Particles member by member (`DynamicsModel.member_step`): x (E, M, 2n), a (E, M, m), block e
        through member e only; a probabilistic member's output is sampled from its Gaussian with `rng`."""
        members, rows, size = x.shape
        if members != self.ensemble_size:
            raise InputError(f"{self.name}: particles laid out for {members} members, the model has {self.ensemble_size}")
        flat_x, flat_a = x.reshape(-1, size), a.reshape(members * rows, -1)
        if members == 1 and (rng is None or not self.probabilistic):
            return self.step(flat_x, flat_a).reshape(x.shape)
        state, rest = self._network_rows(flat_x, flat_a)
        engine = self.engine
        inputs = engine.input_rows(state.astype(np.float32), rest.astype(np.float32)[None])[0]
        if hasattr(engine, "member_block_outputs"):
            mean, variance = engine.member_block_outputs(inputs.reshape(members, rows, -1))
        else:   # (an engine without the fast path: every member on every row, then each block's own member)
            mean, variance = engine.member_outputs(engine.hidden_features(inputs, engine.workspace(len(inputs))))
            block = np.arange(members)
            mean = mean.reshape(members, members, rows, -1)[block, block]
            variance = None if variance is None else variance.reshape(members, members, rows, -1)[block, block]
        if rng is not None and variance is not None:
            mean = mean + np.sqrt(variance) * rng.standard_normal(mean.shape, dtype=np.float32)
        mean = mean.reshape(members * rows, -1).astype(np.float64)
        if engine.residual:
            mean += state
        return self._assemble(flat_x, mean).reshape(x.shape)

    def torch_particles(self, device: str):
        """This model's particle step in PyTorch on `device` (`learning.particles.TorchParticles`), for sampling
        MPC on a GPU; InputError for a model whose inputs need the robot's nominal model (Drake, on the CPU)."""
        if self.structure != PAPER or not hasattr(self.engine, "member_block_outputs"):
            raise InputError(f"{self.name}: only the paper's black box (an ensemble MLP of raw inputs predicting the "
                             f"state) runs on a PyTorch device; this one is {self.structure.label}: use device cpu")
        return TorchParticles(self.engine, device)

    def predict(self, x, a) -> Prediction:
        """Checked one-step prediction: mean and variance (B, 2n) (ensemble spread + aleatoric), member means."""
        states, actions, added = self._checked_pair(x, a)
        state, rest = self._network_rows(states, actions)
        result = predict(self.engine, state, rest)
        mean = self._assemble(states, result.mean.astype(np.float64))
        variance = self._assemble_variance(result.variance.astype(np.float64))
        members = np.stack([self._assemble(states, m.astype(np.float64)) for m in result.member_means])
        member_variances = (None if result.member_variances is None else
                            np.stack([self._assemble_variance(v.astype(np.float64)) for v in result.member_variances]))
        if added:
            return Prediction(mean=mean[0], variance=variance[0], member_means=members[:, 0],
                              member_variances=None if member_variances is None else member_variances[:, 0])
        return Prediction(mean=mean, variance=variance, member_means=members, member_variances=member_variances)

    def _rollout_step(self, x, a):
        # no checks: a state the plant cannot step gives a NaN row (a diverged rollout); one deterministic
        # network has no variance to propagate, so it takes `step`'s fast path
        if self.structure.grey_box or (self.ensemble_size == 1 and not self.probabilistic):
            mean = self.step(x, a)
            return mean, np.zeros_like(mean)
        result = self.predict(x, a)
        return result.mean, result.variance

    def rollout(self, x0, actions, *, propagation: str = "mean", particles: int = 20, seed: int | None = 0,
                implementation: str = "compiled") -> Rollout:
        """Open-loop prediction of steps 1..T (mean, variance (B, T, 2n)) from x0 (B, 2n) under actions (B, T, m)
        (one sequence (1, T, m) serves every initial state).

        "mean" propagation runs in the compiled core (`compiled_core`, implementation "compiled", the default)
        where it covers the model (`rollout_implementation` says which code runs), else on numpy, as
        implementation "numpy" always does: the paper's structure on the fast whole-horizon path, which also
        offers PETS propagation ("ts1", "tsinf": numpy only), other structures step by step."""
        if implementation not in IMPLEMENTATIONS:
            raise InputError(f"rollout implementation must be one of {', '.join(IMPLEMENTATIONS)}, got "
                             f"{implementation!r}")
        if propagation == "mean" and implementation == "compiled" and self._compiled() is not None:
            states = check_batch(x0, self.state_dim, "initial_states")
            sequence = check_batch(actions, self.action_dim, "actions", sequence=True)
            if len(sequence) != len(states):
                if len(sequence) != 1:
                    raise InputError(f"initial_states and actions have different batch sizes: {len(states)} and "
                                     f"{len(sequence)}")
                sequence = np.repeat(sequence, len(states), axis=0)
            mean, variance = compiled_rollout(self._compiled(), states, sequence)
            return Rollout(mean=mean, variance=variance)
        if self.structure == PAPER:
            check_batch(x0, self.state_dim, "initial_states")
            check_batch(actions, self.action_dim, "actions", sequence=True)
            with np.errstate(over="ignore", invalid="ignore"):   # a diverging rollout runs to inf / NaN
                result = rollout(self.engine, x0, actions, propagation=propagation, particles=particles, seed=seed)
            return Rollout(mean=result.mean.astype(np.float64), variance=result.variance.astype(np.float64),
                           particles=result.particles)
        return super().rollout(x0, actions, propagation=propagation, particles=particles, seed=seed)

    @property
    def rollout_implementation(self) -> str:
        """The code a "mean" rollout runs by default: "compiled", or "numpy (why: what the core does not cover)";
        InputError (one line) where the compiled core is not built."""
        self._compiled()
        return "compiled" if self._compiled_why == "" else f"numpy ({self._compiled_why})"

    def _compiled(self):
        """The compiled core's copy of this model (`compiled_core.compiled_model`), made once per engine; None
        where the core does not cover it (`_compiled_why`)."""
        if getattr(self, "_compiled_engine", None) is not self.engine:
            self._compiled_model, self._compiled_why = compiled_model(self)
            self._compiled_engine = self.engine
        return self._compiled_model

    def jacobians(self, x: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """d mean / d(x, a) at each row: A (H, 2n, 2n), B (H, 2n, m) (`linearize`)."""
        return self.linearize(x, a)[1:]

    def linearize(self, x: np.ndarray, a: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Every row at once: the ensemble-mean next states (H, 2n) and d mean / d(x, a), A (H, 2n, 2n),
        B (H, 2n, m), from one float32 forward-mode pass of the network (the engine's `mean_and_jacobian`)
        and, for nominal-model inputs, one evaluation of φ and its Jacobian, entering by the chain rule."""
        x, a = np.asarray(x, dtype=np.float64), np.asarray(a, dtype=np.float64)
        n, S = self.num_joints, self.state_dim
        features = feature_jacobian = None
        if self.features is not None:   # φ and its Jacobian from the same evaluation
            features, feature_jacobian = self.features.values_and_jacobians(x[:, :n], x[:, n:], a)
        state, rest = self.structure.split(x, a, features)
        rows = self.engine.input_rows(state.astype(np.float32), rest.astype(np.float32)[None])[0]
        mean, network = self.engine.mean_and_jacobian(rows)     # (H, out), (H, out, network inputs)
        mean = mean.astype(np.float64)
        if self.engine.residual:      # (in float64, as `step` adds it)
            mean += state
        following = self._assemble(x, mean)
        network = network.astype(np.float64)
        width = S + self.action_dim
        # d(network inputs) / d(x, a): the structure's permutation of [q, v, τ], then φ's Jacobian
        # (plant-step inputs: the plant step's Jacobian [A B] (its v̂ rows for "velocity"), then [x, τ])
        count = len(x)
        order = np.eye(width)
        if self.structure.grey_box:
            part = feature_jacobian if self.structure.predicts == "state" else feature_jacobian[:, n:]
            inputs = np.concatenate([part, np.broadcast_to(order, (count, width, width))], axis=1)
        else:
            if self.structure.predicts == "velocity":
                order = np.vstack([order[n:S], order[:n], order[S:]])    # [v, q, τ]
            inputs = np.broadcast_to(order, (count, width, width))
            if feature_jacobian is not None:
                inputs = np.concatenate([inputs, feature_jacobian], axis=1)
        jacobian = network @ inputs                                      # (H, out, 2n + m)
        if self.structure.predicts == "velocity":
            angle = 0.5 * self.sample_period * jacobian
            angle[:, :, :n] += np.eye(n)
            angle[:, :, n:S] += 0.5 * self.sample_period * np.eye(n)
            jacobian = np.concatenate([angle, jacobian], axis=1)
        return following, jacobian[:, :, :S], jacobian[:, :, S:]


    def describe(self) -> str:
        """Architecture and training of the checkpoint's network (a bare network: its name)."""
        checkpoint = self.checkpoint
        if checkpoint is None:
            return f"model {self.name}: a network ({self.structure.label})"
        config = checkpoint.model_config
        alpha = checkpoint.training_config.alpha if checkpoint.training_config else float("nan")
        return (f"model {self.name}: {type(checkpoint.model).describe_config(config)}, "
                f"{config.ensemble_size} member(s), {'probabilistic' if config.probabilistic else 'deterministic'}, "
                f"{'delta' if config.residual else 'direct'}, {self.structure.label}, derivative alpha {alpha:g}"
                + (f" ({checkpoint.metadata.derivative_source} targets)"
                   if alpha > 0 and checkpoint.metadata.derivative_source else ""))


def checkpoint_model(checkpoint, robot, *, name: str | None = None, for_control: bool = False, **options) -> LearnedModel:
    """A checkpoint's model (the "checkpoint" kind of `dynamics.model_files`): a `LearnedModel` of `robot`
    named `name` or, without one, `trained_name(checkpoint)` (a `name` that is the checkpoint's model type, as
    `mpc --model DD=...`, becomes its trained name too: "DD-naive" where the alpha grid kept naive training); the
    same model for control and evaluation; options: `LearnedModel`'s."""
    model = LearnedModel(checkpoint, name=name, robot=robot, **options)
    if name is None or name == checkpoint.metadata.model_type:
        model.name = trained_name(checkpoint)
    return model


def trained_name(checkpoint) -> str:
    """What a checkpoint is, as tables name it: its model type ("model" where it has none), and for a derivative
    type whose alpha grid kept naive training (alpha 0) that type with "-naive" ("DD-naive": trained like a D), so
    that no table calls a network "DD" that never saw the derivative loss."""
    model_type = checkpoint.metadata.model_type or "model"
    alpha = checkpoint.training_config.alpha if checkpoint.training_config else None
    try:
        derivative = parse_model_type(model_type).derivative
    except InputError:                   # (a type this version does not know)
        derivative = False
    return f"{model_type}-naive" if derivative and alpha == 0 else model_type
