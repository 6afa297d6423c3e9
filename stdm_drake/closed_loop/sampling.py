"""Sampling MPC: the cross-entropy method (`Cem`), its improved version (`Icem`) and model-predictive path
integral control (`Mppi`), each a tagged optimizer of the MPC settings (`optimizer: !Icem {...}`).

Every iteration evaluates all its torque sequences at once: one batched rollout of samples x particles per
horizon step (`sampled_costs.SampledCosts`), no Python loop per sample. How the particles carry a model's uncertainty
(`propagation`, PETS trajectory sampling, Chua et al. 2018):
  "mean"   one particle per sample, the ensemble's mean prediction (a D or DD model's only prediction);
  "tsinf"  `particles` per sample, spread evenly over the ensemble's members, each following its member for
           the whole horizon (TS-infinity); a probabilistic member samples its Gaussian at every step;
  "ts1"    as tsinf, but the particles are shuffled among the members at every step (TS1).
A sample's cost is the tracking cost (`optimizer.TrackingCost`) averaged over its particles, plus
`variance_weight` times the Q-weighted spread of its particles, sum_k w_k tr(Q Var_k): 1 is as much again as
the spread already costs inside the average (the cost of the particles' mean plus that spread), more avoids states
the model is unsure of.

What is sampled: residual joint accelerations (rad/s^2, `noise_std` their spread) on top of an ancillary
control law that every rollout, sampled or applied, runs on its own state: the computed-torque law in the
model's own inertia, with the reference's acceleration as feedforward and the drift the model predicts
at the measured state cancelled (`SamplingSolver.control_law`). A residual acceleration a becomes the torque
dt B_v^+ a, B_v the model's torque Jacobian of the next velocity, so one noise level fits every joint of any
robot, friction and rotor inertia included. Why: sampled raw torques meet a tracking cost whose curvature
spans the UR-10's heavy shoulder and light wrists (10,000 samples of a 0.1 rad move stayed at 100x the optimum's
cost; the affected UR-10's wrist friction, 2.3 N m, is far beyond any torque noise that leaves the shoulder
usable). Every rollout's torques are projected onto the box of the effort limits (the costs of torques the robot
can apply); with the robot's limits on (`constraints.py`) every rollout pays the state limits' exact penalty for
its crossings; the warm start (the previous residuals shifted by one period) is always one of the samples. Where
it runs: NumPy on the CPU (`framework: numpy`, the default), or PyTorch (`framework: torch`) on
`device` cpu or cuda; both draw the torque samples and particle shuffles from one NumPy generator seeded
by `seed`, so for the same settings they return the same torques to float tolerance (a probabilistic
model's Gaussian draws come from the device's own generator: the same in distribution). PyTorch runs the
paper's black box (`LearnedModel.torch_particles`); a model without a PyTorch particle step (a structured
network, whose inputs need Drake's nominal model, or the plant) is refused with `framework: torch`.

Shapes for n joints, m actuated, horizon H, K samples, P particles, state S = 2n: torques (K, H, m) N m."""
import dataclasses

import numpy as np

from stdm_drake.closed_loop.ancillary_law import check_law_stable, computed_torque_law
from stdm_drake.closed_loop.constraints import StateBounds, limits_status
from stdm_drake.closed_loop.optimizer import OptimizerResult, OptimizerSettings, TrackingCost, TrajectoryOptimizer
from stdm_drake.closed_loop.sampled_costs import SampledCosts
from stdm_drake.dynamics.model import PROPAGATIONS
from stdm_drake.errors import InputError
from stdm_drake.dynamics.compiled_core import IMPLEMENTATIONS
from stdm_drake.devices import torch_device

MAX_SAMPLES = 100_000       # torque sequences per iteration
MAX_ROWS = 2_000_000        # samples x particles held at once (S float64 each)
MAX_ITERATIONS = 100        # iterations per control step: more is a run that does not end
MAX_SAMPLED_VALUES = 50_000_000   # samples x horizon x joints: each array of them 400 MB (noise, torques, ...)
MAX_NOISE_STD = 1e4         # rad/s^2: residual accelerations spread wider (1000 g at 1 m) only clip at the limits
MAX_GAIN = 1e6              # the ancillary law's feedback_kp (1/s^2) and feedback_kd (1/s): beyond, no sample period keeps it stable
MAX_SCALE = 1e12            # variance_weight and MPPI's temperature (cost units), as the MPC's weights (mpc.MAX_WEIGHT)
MIN_SCALE = 1e-12           # ... and the smallest noise or temperature: 1e-320 is 0 in all but name (a draw of nothing)
FRAMEWORKS = ("numpy", "torch")


@dataclasses.dataclass
class SamplingSettings(OptimizerSettings):
    """What every sampling optimizer shares (module docstring): samples per iteration, iterations per control
    step, noise_std (rad/s^2: the residual accelerations' spread), propagation ("mean", "ts1", "tsinf") with `particles` per sample
    (a multiple of the ensemble's members), variance_weight >= 0, seed of the draws, framework ("numpy",
    "torch"), device ("cpu", "cuda", "cuda:N"; cuda needs framework torch), implementation (the model's steps
    under framework numpy: "compiled", the compiled core's batched step where it covers the model and the
    propagation is "mean", else "numpy", the reference) and the ancillary law's gains feedback_kp (1/s^2) and
    feedback_kd (1/s) (0 and 0: the law's feedforward alone)."""
    samples: int = 100
    iterations: int = 3
    noise_std: float = 1.0
    propagation: str = "mean"
    particles: int = 1
    variance_weight: float = 0.0
    seed: int = 0
    framework: str = "numpy"
    device: str = "cpu"
    implementation: str = "compiled"
    feedback_kp: float = 225.0
    feedback_kd: float = 30.0

    def tag(self) -> str:
        return f"mpc optimizer !{type(self).__name__}"

    def work_per_step(self, horizon: int) -> int:
        """Every iteration rolls out samples x particles over the horizon."""
        return int(self.samples) * int(self.particles) * int(self.iterations) * int(horizon)

    def validate(self) -> None:
        """InputError (one line) for settings no sampling optimizer can run, before any work: samples, iterations or
        particles out of range, noise not positive or beyond MAX_NOISE_STD, an unknown propagation or framework,
        particles or a variance weight that `propagation: mean` would ignore, a device that does not exist here."""
        tag = self.tag()
        for name, top in (("samples", MAX_SAMPLES), ("iterations", MAX_ITERATIONS), ("particles", MAX_ROWS)):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or not 1 <= value <= top:
                raise InputError(f"{tag} {name} must be an integer in 1..{top}, got {value!r}")
        if isinstance(self.seed, bool) or not isinstance(self.seed, (int, np.integer)) or not 0 <= self.seed < 2 ** 63:
            raise InputError(f"{tag} seed must be an integer in 0..2^63-1, got {self.seed!r}")
        if self.samples * self.particles > MAX_ROWS:
            raise InputError(f"{tag} samples x particles must be at most {MAX_ROWS}, got {self.samples * self.particles}")
        if not (np.isfinite(self.noise_std) and MIN_SCALE <= self.noise_std <= MAX_NOISE_STD):
            raise InputError(f"{tag} noise_std must be in [{MIN_SCALE:g}, {MAX_NOISE_STD:g}] rad/s^2 (a wider spread of "
                             f"residual accelerations only drives every sample into the torque limits), got {self.noise_std}")
        if self.propagation not in PROPAGATIONS:
            raise InputError(f"{tag} propagation must be one of {', '.join(PROPAGATIONS)}, got {self.propagation!r}")
        if self.propagation == "mean" and self.particles > 1:
            raise InputError(f"{tag} particles {self.particles} need `propagation: ts1` or `tsinf` (with `propagation: "
                             "mean` each sample rolls out one particle, the ensemble's mean)")
        if self.propagation == "mean" and self.variance_weight > 0:
            raise InputError(f"{tag} variance_weight {self.variance_weight:g} needs `propagation: ts1` or `tsinf` (one "
                             "particle per sample has no spread to weigh)")
        for name in ("feedback_kp", "feedback_kd"):
            if not (np.isfinite(getattr(self, name)) and 0 <= getattr(self, name) <= MAX_GAIN):
                raise InputError(f"{tag} {name} must be in [0, {MAX_GAIN:g}], got {getattr(self, name)}")
        if not (np.isfinite(self.variance_weight) and 0 <= self.variance_weight <= MAX_SCALE):
            raise InputError(f"{tag} variance_weight must be in [0, {MAX_SCALE:g}], got {self.variance_weight}")
        if self.implementation not in IMPLEMENTATIONS:
            raise InputError(f"{tag} implementation must be one of {', '.join(IMPLEMENTATIONS)}, got "
                             f"{self.implementation!r}")
        if self.framework not in FRAMEWORKS:
            raise InputError(f"{tag} framework must be one of {', '.join(FRAMEWORKS)}, got {self.framework!r}")
        if self.framework == "numpy" and self.device != "cpu":
            raise InputError(f"{tag} device {self.device!r} needs `framework: torch` (NumPy runs on the cpu)")
        if self.framework == "torch":
            try:
                torch_device(self.device)
            except InputError as error:
                raise InputError(f"{tag} {error}") from None


class SamplingSolver(TrajectoryOptimizer):
    """What CEM, iCEM and MPPI share: the noise, the ancillary control law, the batched costs, the plan kept
    between control steps and the result.

    The samplers search over residual accelerations (H, n) rad/s^2; every rollout, the sampled ones and the
    applied one, turns them into torques through the law of `control_law`, u_k = clip(feedforward_k + map a_k +
    gain (r_k - x_k)), evaluated on its own state x_k (the computed-torque law: kp = `feedback_kp` 1/s^2,
    kd = `feedback_kd` 1/s in the model's own inertia), so every sample's rollout follows the reference and
    the samples differ in how well. With the exact model of the affected UR-10 the law alone tracks a
    0.1 rad move to 1.7e-7 rad^2; raw torque samples without it stayed near 1e-4."""

    def __init__(self, model, cost: TrackingCost, effort_limit: np.ndarray, settings: SamplingSettings,
                 bounds: StateBounds | None = None):
        super().__init__(model, cost, effort_limit, bounds)
        settings.validate()
        check_law_stable(settings, getattr(model, "sample_period", None) or 0.0)
        self.settings = settings
        self.rng = np.random.default_rng(int(settings.seed))
        self.costs = SampledCosts(model, cost, effort_limit, settings, self.rng, bounds)
        self.plan = None        # the last solve's feedforward torques, shifted by one period
        # what runs the control step (`mpc.control_step_implementation`: the real-time line names it)
        notes = [note for note in (self.costs.steps, self.costs.note) if note]
        self.implementation = f"numpy ({'; '.join([type(self).__name__] + notes)})"

    def clip(self, u: np.ndarray) -> np.ndarray:
        return np.clip(u, -self.effort_limit, self.effort_limit)

    def noise(self, count: int, horizon: int) -> np.ndarray:
        """(count, H, n) white standard normal draws (iCEM overrides: colored)."""
        return self.rng.standard_normal((count, horizon, self.state_dim // 2))

    def control_law(self, x0: np.ndarray, reference: np.ndarray, u_ff: np.ndarray, offset: np.ndarray):
        """The ancillary law at the measured state x0 (S,): `ancillary_law.computed_torque_law` on the model's
        step from x0 under u_ff,0."""
        with np.errstate(all="ignore"):
            following, _, B = self.linearize(x0[None], u_ff[:1])
        return computed_torque_law(following[0], B[0], x0, reference, u_ff, offset, self.settings,
                                   getattr(self.model, "sample_period", None) or 1.0, self.joints)

    def start(self, x0, reference, u_ff, offset, x_init):
        """The residual plan (H, n) rad/s^2 to search from (the last solve's, shifted; zero on a first step or after
        a fallback: x_init None) and the control law."""
        horizon = len(u_ff)
        if x_init is None or self.plan is None or len(self.plan) != horizon:
            self.plan = np.zeros((horizon, self.state_dim // 2))
        return self.plan, self.control_law(x0, reference, u_ff, offset)

    def torques(self, residuals: np.ndarray, law) -> np.ndarray:
        """Feedforward torques (..., H, m) of residual accelerations (..., H, n) rad/s^2 on the law's feedforward."""
        feedforward, _, acceleration_map = law
        return self.clip(feedforward + residuals @ acceleration_map)

    def evaluate(self, x0, residuals, law, reference, u_ff, offset):
        """costs (K,) of residual accelerations (K, H, n) on top of the control law."""
        return self.costs(x0, self.torques(residuals, law), law[1], reference, u_ff, offset)[0]

    def result(self, x0, residual, law, reference, u_ff, offset, iterations: int) -> OptimizerResult:
        """The torques the chosen residual and the control law apply along the model's mean prediction (the first is
        applied; the prediction is what the disturbance observer compares with the next measurement); the
        residual is kept, shifted by one period, for the next control step."""
        feedforward, gain = self.torques(residual, law), law[1]
        x = np.empty((len(feedforward) + 1, self.state_dim))
        u = np.empty_like(feedforward)
        x[0] = x0
        with np.errstate(all="ignore"):
            for k in range(len(feedforward)):
                u[k] = self.clip(feedforward[k] + gain @ (reference[k] - x[k]))
                x[k + 1] = self.predict(x[k], u[k], offset)
        finite = bool(np.all(np.isfinite(x)) and np.all(np.isfinite(u)))
        self.plan = np.concatenate([residual[1:], residual[-1:]])
        active, slack = (limits_status(self.bounds, x[1:], u, self.effort_limit) if finite and self.bounds is not None
                         else (False, 0.0))
        return OptimizerResult(u=u, x=x, cost=self.cost(x, u, reference, u_ff) if finite else float("inf"),
                               iterations=iterations, finite=finite, constraint_active=active, slack=slack)


# -- CEM ---------------------------------------------------------------------------------------------------

@dataclasses.dataclass
class Cem(SamplingSettings):
    """The cross-entropy method (PETS' optimizer, mbrl-lib's `CEMOptimizer`): each iteration samples `samples`
    Gaussian torque sequences around the mean, keeps the `elites` cheapest and moves the mean and spread
    towards theirs, `smoothing` of the old kept (0: none). The best sequence evaluated is applied."""
    samples: int = 400
    iterations: int = 5
    noise_std: float = 1.0
    elites: int = 40
    smoothing: float = 0.1

    def validate(self) -> None:
        super().validate()
        check_elites(self)

    def solver(self, model, cost: TrackingCost, effort_limit: np.ndarray, horizon: int,
               bounds: StateBounds | None = None) -> "CemSolver":
        check_sampled_size(self, horizon, model.state_dim // 2)
        return CemSolver(model, cost, effort_limit, self, bounds)


def check_sampled_size(settings, horizon: int, joints: int) -> None:
    """InputError (one line, with the estimate) before any work where an iteration's arrays of samples x horizon x
    joints (the noise, the torques: float64) exceed MAX_SAMPLED_VALUES: fewer samples or a shorter horizon."""
    values = int(settings.samples) * int(horizon) * int(joints)
    if values > MAX_SAMPLED_VALUES:
        raise InputError(f"{settings.tag()} samples {settings.samples} x horizon {horizon} x {joints} joints = "
                         f"{values:,} values per array (about {values * 8 / 1e9:.1f} GB each, several held per "
                         f"iteration), beyond the budget of {MAX_SAMPLED_VALUES:,}: fewer samples or a shorter horizon")


def check_elites(settings) -> None:
    """What CEM and iCEM share: elites within the population (`samples`), smoothing in [0, 1)."""
    if isinstance(settings.elites, bool) or not isinstance(settings.elites, (int, np.integer)) \
            or not 1 <= settings.elites <= settings.samples:
        raise InputError(f"{settings.tag()} elites must be an integer in 1..{settings.samples} (the population), got "
                         f"{settings.elites!r}")
    if not 0 <= settings.smoothing < 1:
        raise InputError(f"{settings.tag()} smoothing must be in [0, 1), got {settings.smoothing}")


def elite_update(samples: np.ndarray, costs: np.ndarray, settings, mean: np.ndarray, std: np.ndarray, best: tuple):
    """One CEM step, CEM's and iCEM's: the `settings.elites` cheapest samples (K', H, n), the mean and spread (H, n)
    moved towards theirs (`settings.smoothing` of the old kept), and the best (sequence, cost) seen so far."""
    order = np.argsort(costs, kind="stable")[:settings.elites]
    if costs[order[0]] < best[1]:
        best = (samples[order[0]], costs[order[0]])
    elites = samples[order]
    mean = settings.smoothing * mean + (1 - settings.smoothing) * elites.mean(axis=0)
    std = settings.smoothing * std + (1 - settings.smoothing) * elites.std(axis=0)
    return elites, mean, std, best


class CemSolver(SamplingSolver):
    def solve(self, x0, u_init, reference, u_ff, offset=None, x_init=None) -> OptimizerResult:
        offset = np.zeros(self.state_dim) if offset is None else offset
        settings = self.settings
        mean, law = self.start(x0, reference, u_ff, offset, x_init)
        std = np.full(mean.shape, self.settings.noise_std)
        best, best_cost = mean, np.inf
        for _ in range(settings.iterations):
            samples = mean + std * self.noise(settings.samples, len(mean))
            samples[0] = mean
            costs = self.evaluate(x0, samples, law, reference, u_ff, offset)
            elites, mean, std, (best, best_cost) = elite_update(samples, costs, settings, mean, std, (best, best_cost))
        return self.result(x0, best, law, reference, u_ff, offset, settings.iterations)


# -- iCEM --------------------------------------------------------------------------------------------------

@dataclasses.dataclass
class Icem(SamplingSettings):
    """The improved CEM (Pinneri et al. 2020) at its low budget: CEM with colored noise (power spectrum
    1/f^colored_noise_exponent along the horizon: smooth torques), a population that shrinks by
    `population_decay` each iteration (never below 2 elites), a fraction `keep_elites` of the last elites
    carried into the next iteration and, shifted by one period, into the next control step, and the mean
    among the last iteration's samples. The best sequence evaluated is applied."""
    samples: int = 100
    iterations: int = 3
    noise_std: float = 1.0
    elites: int = 10
    smoothing: float = 0.1
    population_decay: float = 1.25
    colored_noise_exponent: float = 2.0
    keep_elites: float = 0.3

    def validate(self) -> None:
        super().validate()
        check_elites(self)
        # (beyond samples / (2 elites), or the default, the population is at its floor after one iteration)
        top = max(self.samples / (2 * self.elites), Icem.population_decay) if self.iterations > 1 else np.inf
        if not (np.isfinite(self.population_decay) and 1 <= self.population_decay <= top):
            raise InputError(f"{self.tag()} population_decay must be in [1, {top:g}] (beyond samples / (2 elites) the "
                             f"population is at its floor of 2 x elites after one iteration), got {self.population_decay}")
        if not (np.isfinite(self.colored_noise_exponent) and 0 <= self.colored_noise_exponent <= 10):
            raise InputError(f"{self.tag()} colored_noise_exponent must be in [0, 10], got {self.colored_noise_exponent}")
        if not 0 <= self.keep_elites <= 1:
            raise InputError(f"{self.tag()} keep_elites must be in [0, 1], got {self.keep_elites}")

    def solver(self, model, cost: TrackingCost, effort_limit: np.ndarray, horizon: int,
               bounds: StateBounds | None = None) -> "IcemSolver":
        check_sampled_size(self, horizon, model.state_dim // 2)
        return IcemSolver(model, cost, effort_limit, self, bounds)


def colored_noise(rng: np.random.Generator, count: int, horizon: int, joints: int, exponent: float) -> np.ndarray:
    """(count, horizon, joints) Gaussian sequences of unit variance whose power spectrum along the horizon falls
    as 1/f^exponent (0: white), drawn in the frequency domain (frequencies below 1/horizon as 1/horizon)."""
    frequencies = np.fft.rfftfreq(horizon)
    frequencies[0] = frequencies[1] if horizon > 1 else 1.0
    amplitude = frequencies ** (-exponent / 2.0)
    real = rng.standard_normal((count, joints, len(amplitude)))
    imaginary = rng.standard_normal((count, joints, len(amplitude)))
    imaginary[..., 0] = 0.0                  # (the mean and, for an even horizon, the Nyquist term are real)
    if horizon % 2 == 0:
        imaginary[..., -1] = 0.0
    signal = np.fft.irfft(amplitude * (real + 1j * imaginary), n=horizon, axis=-1)
    # variance of each sample: (a_0^2 + 4 sum of the middle a_f^2 + a_Nyquist^2) / horizon^2
    power = amplitude ** 2
    middle = power[1:-1] if horizon % 2 == 0 else power[1:]
    variance = (power[0] + 4.0 * middle.sum() + (power[-1] if horizon % 2 == 0 and horizon > 1 else 0.0)) / horizon ** 2
    return (signal / np.sqrt(variance)).transpose(0, 2, 1)


class IcemSolver(SamplingSolver):
    def __init__(self, model, cost, effort_limit, settings: Icem, bounds: StateBounds | None = None):
        super().__init__(model, cost, effort_limit, settings, bounds)
        self.kept = None           # the last control step's elites shifted by one period (E', H, m)

    def noise(self, count: int, horizon: int) -> np.ndarray:
        return colored_noise(self.rng, count, horizon, self.state_dim // 2, self.settings.colored_noise_exponent)

    def solve(self, x0, u_init, reference, u_ff, offset=None, x_init=None) -> OptimizerResult:
        offset = np.zeros(self.state_dim) if offset is None else offset
        settings = self.settings
        if x_init is None:
            self.kept = None       # (the first control step, or one after a fallback: nothing to carry)
        mean, law = self.start(x0, reference, u_ff, offset, x_init)
        std = np.full(mean.shape, self.settings.noise_std)
        best, best_cost, carried = mean, np.inf, self.kept
        elites = None
        for iteration in range(settings.iterations):
            population = max(int(settings.samples * settings.population_decay ** -iteration), 2 * settings.elites)
            samples = mean + std * self.noise(population, len(mean))
            extra = [mean[None]] if iteration == settings.iterations - 1 or iteration == 0 else []
            if carried is not None and len(carried):
                extra.append(carried[:max(1, int(round(settings.keep_elites * len(carried))))])
            samples = np.concatenate([samples] + extra)
            costs = self.evaluate(x0, samples, law, reference, u_ff, offset)
            elites, mean, std, (best, best_cost) = elite_update(samples, costs, settings, mean, std, (best, best_cost))
            carried = elites if settings.keep_elites > 0 else None
        if settings.keep_elites > 0 and elites is not None:
            self.kept = np.concatenate([elites[:, 1:], elites[:, -1:]], axis=1)
        return self.result(x0, best, law, reference, u_ff, offset, settings.iterations)


# -- MPPI --------------------------------------------------------------------------------------------------

@dataclasses.dataclass
class Mppi(SamplingSettings):
    """Model-predictive path integral control (Williams et al. 2017; pytorch_mppi's `MPPI`): each iteration
    perturbs the current torques with `samples` Gaussian sequences and replaces them by the samples' average
    weighted by exp(-(cost - lowest cost) / temperature); temperature in the cost's units (the tracking cost
    of the MPC settings), lower trusts the best samples more."""
    samples: int = 100
    iterations: int = 1
    noise_std: float = 1.0
    temperature: float = 1.0

    def validate(self) -> None:
        super().validate()
        if not (np.isfinite(self.temperature) and MIN_SCALE <= self.temperature <= MAX_SCALE):
            raise InputError(f"{self.tag()} temperature must be in [{MIN_SCALE:g}, {MAX_SCALE:g}] (cost units), got "
                             f"{self.temperature}")

    def solver(self, model, cost: TrackingCost, effort_limit: np.ndarray, horizon: int,
               bounds: StateBounds | None = None) -> "MppiSolver":
        check_sampled_size(self, horizon, model.state_dim // 2)
        return MppiSolver(model, cost, effort_limit, self, bounds)


class MppiSolver(SamplingSolver):
    def solve(self, x0, u_init, reference, u_ff, offset=None, x_init=None) -> OptimizerResult:
        offset = np.zeros(self.state_dim) if offset is None else offset
        settings = self.settings
        u, law = self.start(x0, reference, u_ff, offset, x_init)
        iterations = 0
        for _ in range(settings.iterations):
            samples = u + settings.noise_std * self.noise(settings.samples, len(u))
            samples[0] = u
            costs = self.evaluate(x0, samples, law, reference, u_ff, offset)
            iterations += 1
            if not np.isfinite(costs).any():
                break
            weights = np.exp(-(costs - costs.min()) / settings.temperature)
            u = np.einsum("k,khj->hj", weights / weights.sum(), samples)
        return self.result(x0, u, law, reference, u_ff, offset, iterations)
