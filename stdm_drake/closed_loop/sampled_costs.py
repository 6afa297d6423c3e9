"""The batched costs of sampling MPC (`sampling`): one rollout of all samples x particles per horizon step, on
NumPy or on a PyTorch device, through a model's particle step (`DynamicsModel.member_step`, or
`LearnedModel.torch_particles`); how the particles carry the ensemble's spread: `sampling`'s docstring.

Shapes for n joints, m actuated, horizon H, K samples, P particles over E members, state S = 2n.
"""
import numpy as np

from stdm_drake.closed_loop.optimizer import TrackingCost
from stdm_drake.errors import InputError
from stdm_drake.dynamics.compiled_core import compiled_model


class SampledCosts:
    """The costs of K feedforward torque sequences from x0: one batched rollout of K x P particles per horizon
    step, on NumPy or on a PyTorch device (module docstring). Each particle applies, at each step, its
    sample's feedforward plus the ancillary feedback `gain` (m, 2n) on its own error from the reference,
    clipped to the effort limits: u = clip(u_bar_k + gain (r_k - x)), and pays the effort of that torque and, with
    state `bounds` (`constraints.StateBounds`), the exact penalty of its crossings of the state limits."""

    def __init__(self, model, cost: TrackingCost, effort_limit: np.ndarray, settings,
                 rng: np.random.Generator, bounds=None):
        self.model, self.settings, self.rng, self.bounds = model, settings, rng, bounds
        probabilistic = bool(getattr(model, "probabilistic", False))
        members = int(getattr(model, "ensemble_size", 1))
        sampled = settings.propagation != "mean" and (members > 1 or probabilistic)
        self.propagation = settings.propagation if sampled else "mean"
        self.members = members if sampled else 1
        self.particles = settings.particles if sampled else 1
        # what the settings ask that this model cannot give (said on `mpc`'s real-time line, not silent)
        self.note = "" if sampled or settings.propagation == "mean" else (
            f"propagation {settings.propagation} with {settings.particles} particles runs as mean: "
            f"{getattr(model, 'name', 'the model')} has one deterministic member")
        if self.particles % self.members:
            raise InputError(f"{settings.tag()} particles ({settings.particles}) must be a multiple of the model's "
                             f"{members} ensemble members (each member carries as many)")
        self.q, self.r = np.diag(cost.Q).copy(), np.diag(cost.R).copy()
        self.effort_limit = np.asarray(effort_limit, dtype=float)
        self.step_weights = cost.step_weights
        self.torch = None
        self.put = lambda values: values
        # the mean step of framework numpy: the compiled core's batched step where it covers the model
        self.compiled, self.steps = None, ""
        if settings.framework == "numpy":
            if self.propagation != "mean":
                self.steps = f"{self.propagation} member steps numpy"
            elif settings.implementation == "numpy":
                self.steps = "the model's steps numpy"
            else:
                self.compiled, why_not = compiled_model(model)
                self.steps = ("the model's steps compiled" if self.compiled is not None else
                              f"the model's steps numpy: the compiled core does not cover {why_not}")
        if settings.framework == "torch":
            import torch
            if not hasattr(model, "torch_particles"):
                raise InputError(f"{settings.tag()} framework torch: model {model.name} has no PyTorch particle step "
                                 "(the paper's black box has); use framework numpy")
            self.torch = model.torch_particles(settings.device)
            device = self.torch.device
            self.generator = torch.Generator(device=device).manual_seed(int(settings.seed))
            self.put = lambda values: torch.as_tensor(np.asarray(values, dtype=np.float32), device=device)
            self.to_index = lambda values: torch.as_tensor(values, dtype=torch.long, device=device)

    def __call__(self, x0: np.ndarray, u: np.ndarray, gain: np.ndarray, reference: np.ndarray, u_ff: np.ndarray,
                 offset: np.ndarray, keep_states: bool = False):
        """costs (K,) of feedforward torques u (K, H, m) (inf where a rollout left the finite numbers) and, with
        keep_states, the particles' states (H, P, K, S) (the member of particle p is p // (P / E) under tsinf)."""
        samples, horizon, joints = u.shape
        xp = np if self.torch is None else __import__("torch")
        put = self.put
        particles, members, size = self.particles, self.members, len(x0)
        rows = particles * samples // members
        weights = self.step_weights(horizon)
        q, r, limit, gain_t = put(self.q), put(self.r), put(self.effort_limit), put(gain.T)
        if self.bounds is not None:
            lower, upper = put(np.maximum(self.bounds.lower, -1e30)), put(np.minimum(self.bounds.upper, 1e30))
            penalty_weight = self.bounds.penalty_weight
        x = xp.broadcast_to(put(x0), (members, rows, size))
        offset_d, torques, references, feedforward = put(offset), put(u), put(reference), put(u_ff)
        total, kept = 0.0, []
        with np.errstate(all="ignore"):
            for k in range(horizon):
                a = xp.broadcast_to(torques[:, k], (particles, samples, joints)).reshape(members, rows, joints)
                a = xp.clip(a + (references[k] - x) @ gain_t, -limit, limit)
                effort = ((a - feedforward[k]) ** 2 @ r).reshape(particles, samples).mean(0)
                x = self._step(x, a, xp) + offset_d
                states = x.reshape(particles, samples, size)
                total = total + effort + float(weights[k]) * ((states - references[k + 1]) ** 2 @ q).mean(0)
                if self.bounds is not None:     # the exact penalty of the state limits, each particle's
                    slack = (xp.clip(states - upper, 0, None) + xp.clip(lower - states, 0, None))
                    total = total + penalty_weight * (slack + 0.5 * slack ** 2).sum(-1).mean(0)
                if self.settings.variance_weight > 0 and particles > 1:
                    spread = ((states - states.mean(0)) ** 2).mean(0)
                    total = total + self.settings.variance_weight * float(weights[k]) * (spread @ q)
                if keep_states:
                    kept.append(states)
        costs = total if self.torch is None else total.cpu().double().numpy()
        costs = np.where(np.isfinite(costs), costs, np.inf)
        if not keep_states:
            return costs, None
        states = xp.stack(kept)
        return costs, states if self.torch is None else states.cpu().double().numpy()

    def _step(self, x, a, xp):
        size, joints = x.shape[-1], a.shape[-1]
        if self.propagation == "mean":
            if self.torch is not None:
                return self.torch.mean_step(x.reshape(-1, size), a.reshape(-1, joints)).reshape(x.shape)
            if self.compiled is not None:
                return self.compiled.step_rows(np.ascontiguousarray(x.reshape(-1, size)),
                                               np.ascontiguousarray(a.reshape(-1, joints))).reshape(x.shape)
            return self.model.step(x.reshape(-1, size), a.reshape(-1, joints)).reshape(x.shape)
        if self.propagation == "tsinf":
            return self._member_step(x, a)
        order = self.rng.permutation(x.shape[0] * x.shape[1])    # TS1: the particles change members every step
        index = order if self.torch is None else self.to_index(order)
        moved = self._member_step(x.reshape(-1, size)[index].reshape(x.shape),
                                  a.reshape(-1, joints)[index].reshape(a.shape))
        back = xp.empty_like(moved.reshape(-1, size))
        back[index] = moved.reshape(-1, size)
        return back.reshape(x.shape)

    def _member_step(self, x, a):
        if self.torch is not None:
            return self.torch.step(x, a, self.generator)
        return self.model.member_step(x, a, self.rng)
