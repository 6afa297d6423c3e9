"""`identify`: a robot's parameters from one of its datasets, settings chosen on validation data.

On the training trajectories, for every candidate setting (Coulomb velocity scale v_s, regularization
lambda and, for smoothed derivatives, the Savitzky-Golay window) the physically consistent fit
(`fit.consistent_fit`); the setting with the smallest torque error on the validation trajectories wins
(a v_s whose Coulomb term would be unstable at the plant step is skipped). With it: least squares on the
base parameters (condition number, covariance), and the test trajectories' torque errors, on the data's
own states and, for simulated data, on the true ones. Where the dataset records the plant effects it was
simulated with, every identified friction and rotor coefficient and every link's inertia (the link's
welded group with any payload) stands beside the true value.
"""
from __future__ import annotations

import dataclasses

import numpy as np

from stdm_drake.errors import InputError
from stdm_drake.identification.fit import (
    consistent_fit, fits_window, identification_data, least_squares, relative_torque_error
)
from stdm_drake.identification.identified import Identification, IdentifiedRobot, link_inertia
from stdm_drake.identification.regressor import LINK_PARAMETERS, InverseDynamicsRegressor
from stdm_drake.robots.plant import DEFAULT_PLANT_TIME_STEP, robot_joint_limits
from stdm_drake.robots.plant_effects_check import coulomb_stability_gains
from stdm_drake.robots.effects import PlantEffects

VELOCITY_SCALES = (0.01, 0.05, 0.2)            # rad/s: the Coulomb term's tanh smoothing
REGULARIZATIONS = (1e-8, 1e-6, 1e-4, 1e-2)     # toward the description's parameters (relative)
SMOOTHING_WINDOWS = (5, 9, 15, 21, 31, 45)            # samples (odd) of the Savitzky-Golay differentiator
MAX_CANDIDATES = 100   # of each list above that a user gives


@dataclasses.dataclass
class IdentifySettings:
    """The candidate settings (`VELOCITY_SCALES`, `REGULARIZATIONS`, `SMOOTHING_WINDOWS`) and the
    derivative source ("true" or "smoothed")."""
    derivative_source: str = "true"
    velocity_scales: tuple = VELOCITY_SCALES
    regularizations: tuple = REGULARIZATIONS
    windows: tuple = SMOOTHING_WINDOWS

    def validate(self) -> None:
        for name in ("velocity_scales", "regularizations", "windows"):
            values = getattr(self, name)
            if not len(values) or not all(np.isfinite(value) for value in values):
                raise InputError(f"identify: {name.replace('_', ' ')} must be a non-empty list of numbers")
            if len(values) > MAX_CANDIDATES:   # (each is a fit of its own: thousands would run for hours)
                raise InputError(f"identify: at most {MAX_CANDIDATES} {name.replace('_', ' ')}, got {len(values)}")
        if not (1e-6 <= min(self.velocity_scales) and max(self.velocity_scales) <= 1e3):   # (1e-320: a sign function;
            raise InputError("identify: velocity scales must be in [1e-06, 1000] rad/s")   # 1e300: no friction at all)
        if min(self.regularizations) < 0 or max(self.regularizations) > 1e6:
            raise InputError("identify: regularizations must be in [0, 1e6] (beyond, the fit is the description's)")
        for window in self.windows:
            if window != 1 and (window < 5 or window % 2 == 0):
                raise InputError(f"identify: smoothing windows must be 1 (no smoothing) or odd numbers of samples "
                                 f">= 5, got {window}")


def usable_windows(dataset, split, settings: IdentifySettings, given: bool = False) -> tuple:
    """The smoothing windows of `settings` that leave samples inside the split's shortest trajectory ((0,): no
    smoothing, for true derivatives); InputError (one line) where none does, or where `given` (the user's
    --windows, not the default candidates) and any one does not: a candidate is refused, never dropped."""
    if settings.derivative_source != "smoothed":
        return (0,)
    shortest = min(dataset.trajectory(int(i)).num_steps for i in [*split.train, *split.val, *split.test])
    windows = tuple(window for window in settings.windows if fits_window(shortest, window))
    if given and windows and len(windows) < len(settings.windows):
        longer = [window for window in settings.windows if window not in windows]
        widest = 2 * ((shortest - 2) // 2) + 1
        fix = f"give windows of at most {widest}" if widest >= 5 else "give 1 (no smoothing)"
        several = len(longer) > 1
        raise InputError(f"identify: smoothing window{'s' if several else ''} {longer} of --windows "
                         f"{list(settings.windows)} leave{'' if several else 's'} no sample inside trajectories of "
                         f"{shortest} steps (the split's shortest); {fix}")
    if not windows:
        raise InputError(f"identify: no smoothing window of {list(settings.windows)} fits trajectories of {shortest} "
                         "steps")
    return windows


def _unstable_joints(scale: float, parameters: np.ndarray, regressor, robot, time_step: float) -> np.ndarray:
    """The joints (indices) whose identified Coulomb term of velocity scale `scale` is unstable at the plant step."""
    gains = coulomb_stability_gains(_effects(parameters, regressor, scale, ""), robot, time_step)
    return np.zeros(0, dtype=int) if gains is None else np.flatnonzero(gains > 1.0)


def _stable_fit(rows, target, prior, regressor, robot, time_step: float, scale: float, regularization: float):
    """(parameters, the joints whose Coulomb friction is held at 0): the consistent fit, refitted with the Coulomb
    friction of each joint whose explicit Coulomb term the plant step cannot integrate held at 0 (there the data cannot
    tell it from viscous friction: on a light joint with viscous friction and no Coulomb friction, the fit splits the
    damping between both), until none is unstable."""
    n, offset, zero = regressor.num_joints, 10 * len(regressor.links), np.zeros(0, dtype=int)
    while True:
        parameters = consistent_fit(rows, target, prior, len(regressor.links), regularization,
                                    zero=offset + n + zero)
        unstable = _unstable_joints(scale, parameters, regressor, robot, time_step)
        if not len(unstable) or set(unstable) <= set(zero):
            return parameters, zero
        zero = np.union1d(zero, unstable)


def _effects(parameters: np.ndarray, regressor: InverseDynamicsRegressor, scale: float, source: str):
    n, links = regressor.num_joints, regressor.links
    joint = parameters[10 * len(links):]
    return PlantEffects(source=source, joint_damping=joint[:n].tolist(), coulomb_friction=joint[n:2 * n].tolist(),
                        coulomb_velocity_scale=[float(scale)], rotor_inertia=joint[2 * n:].tolist(),
                        link_inertia={link: link_inertia(parameters[10 * k:10 * k + 10]) for k, link in enumerate(links)})


def usable_scales(settings: IdentifySettings, robot, given: bool = False) -> tuple:
    """The Coulomb velocity scales of `settings` within every arm joint's speed range (its velocity limit; a wider one
    never lets the friction reach its level: the plant effects' own rule); InputError (one line) where none is, or where
    `given` (the user's --velocity-scales, not the defaults) and one is not: a given candidate is refused, not dropped."""
    speed = robot_joint_limits(robot).velocity
    joint = int(np.argmin(speed))
    scales = tuple(scale for scale in settings.velocity_scales if scale <= speed[joint])
    if not scales or (given and len(scales) < len(settings.velocity_scales)):
        raise InputError(f"identify: --velocity-scales {max(settings.velocity_scales):g} rad/s is wider than "
                         f"{robot.joint_names[joint]}'s whole speed range (velocity limit {speed[joint]:g} rad/s), so its "
                         f"Coulomb friction would never reach its level; give scales of at most {speed[joint]:g}")
    return scales


def identify(dataset, robot, split, settings: IdentifySettings | None = None, announce=lambda line: None):
    """(IdentifiedRobot, report dict) of `dataset` (of `robot`) with `split` (train / val / test indices)."""
    settings = settings or IdentifySettings()
    settings.validate()
    if not len(split.train) or not len(split.val):
        raise InputError("identify needs training and validation trajectories")
    scales = usable_scales(settings, robot)
    source = settings.derivative_source
    regressor = InverseDynamicsRegressor(robot)
    prior = regressor.parameters()
    time_step = dataset.metadata.plant_time_step or DEFAULT_PLANT_TIME_STEP
    windows = usable_windows(dataset, split, settings)
    candidates, best = [], None
    for window in windows:
        train = identification_data(regressor, dataset, split.train, source, window or None)
        val = identification_data(regressor, dataset, split.val, source, window or None)
        for scale in scales:
            rows, target = train.system(regressor, scale)
            for regularization in settings.regularizations:
                setting = dict(window=window, velocity_scale=scale, regularization=regularization)
                try:
                    parameters, zero = _stable_fit(rows, target, prior, regressor, robot, time_step, scale,
                                                   regularization)
                except InputError as error:
                    candidates.append(dict(setting, val_torque_error=None, skipped=str(error)))
                    continue
                error = relative_torque_error(val.predicted_torque(regressor, parameters, scale), val.torque)[0]
                held = [robot.joint_names[j] for j in zero]
                candidates.append(dict(setting, val_torque_error=error, coulomb_held_at_zero=held))
                if best is None or error < best[0]:
                    best = (error, window, scale, regularization, parameters, train, held)
        announce(f"identify: {f'smoothing window {window} samples' if window else 'no smoothing'}: best validation torque "
                 f"error so far {best[0] if best else float('nan'):.3g}")
    if best is None:
        raise InputError("identify: no candidate setting gave a usable fit (" + "; ".join(
            sorted({candidate["skipped"] for candidate in candidates})) + ")")
    val_error, window, scale, regularization, parameters, train, held = best
    rows, target = train.system(regressor, scale)
    ordinary = least_squares(rows, target)
    report = dict(written_by="stdm-drake identify", robot=robot.name, dataset=str(dataset.path),
                  dataset_sha256=dataset.sha256, derivative_source=source, smoothing_window=window or None,
                  split={key: [int(i) for i in value] for key, value in split.as_dict().items()},
                  samples_train=int(len(target) // regressor.num_joints), parameters=list(regressor.names),
                  links=list(regressor.links), candidates=candidates,
                  chosen=dict(velocity_scale=scale, regularization=regularization, val_torque_error=val_error,
                              coulomb_held_at_zero=held),
                  least_squares=dict(base_parameters=int(len(ordinary.base)), condition_number=ordinary.condition,
                                     residual_std=ordinary.residual_std,
                                     base=[regressor.names[i] for i in ordinary.base],
                                     relative_std=_json_numbers(_relative_std(ordinary))),
                  description=prior.tolist(), identified=parameters.tolist())
    test_error = float("nan")   # (the file's record; the report leaves out "test" without test trajectories)
    if len(split.test):
        test = identification_data(regressor, dataset, split.test, source, window or None)
        test_error, per_joint = relative_torque_error(test.predicted_torque(regressor, parameters, scale), test.torque)
        ls_error = relative_torque_error(test.predicted_torque(regressor, ordinary.parameters, scale), test.torque)[0]
        nominal_error = relative_torque_error(test.predicted_torque(regressor, prior, scale), test.torque)[0]
        report["test"] = dict(torque_error=test_error, torque_error_per_joint=per_joint.tolist(),
                              least_squares_torque_error=ls_error, description_torque_error=nominal_error)
        if source != "true" and dataset.is_simulated:
            exact = identification_data(regressor, dataset, split.test, "true")
            report["test"]["torque_error_on_true_states"] = relative_torque_error(
                exact.predicted_torque(regressor, parameters, scale), exact.torque)[0]
    truth = dataset.metadata.plant_effects
    if truth is not None:
        report["truth"] = _against_truth(regressor, parameters, regressor.parameters(truth))
    record = Identification(robot=robot.name, robot_model_sha256=robot.model_sha256(), dataset=str(dataset.path),
                            dataset_sha256=dataset.sha256, sample_period=dataset.sample_period,
                            plant_time_step=time_step, derivative_source=source, smoothing_window=int(window),
                            split=report["split"], coulomb_velocity_scale=float(scale),
                            regularization=float(regularization), test_torque_error=float(test_error))
    effects = _effects(parameters, regressor, scale, f"identified by stdm-drake identify from {dataset.path.name} "
                                                     f"(sha256 {dataset.sha256[:12]})")
    identified = IdentifiedRobot(effects=effects, identification=record)
    identified.check_robot(robot)    # a model every command can build (before anything is written)
    return identified, report


def _json_numbers(values) -> list:
    """A list for JSON: non-finite values (a zero true value's relative error) as None."""
    return [float(value) if np.isfinite(value) else None for value in values]


def _relative_std(fit) -> np.ndarray:
    """Standard deviation / |value| of each base parameter (inf for a zero value)."""
    std = np.sqrt(np.diag(fit.covariance))
    values = np.abs(fit.parameters[fit.base])
    return np.divide(std, values, out=np.full_like(std, np.inf), where=values > 0)


def _against_truth(regressor, identified: np.ndarray, truth: np.ndarray) -> dict:
    """Per joint parameter: identified, true and relative error; per link: the identified and true values."""
    n, links = regressor.num_joints, len(regressor.links)
    joint_part = {}
    for k, kind in enumerate(("viscous", "coulomb", "rotor_inertia")):
        mine = identified[10 * links + k * n:10 * links + (k + 1) * n]
        true = truth[10 * links + k * n:10 * links + (k + 1) * n]
        error = np.divide(np.abs(mine - true), np.abs(true), out=np.full(n, np.nan), where=np.abs(true) > 0)
        joint_part[kind] = dict(identified=mine.tolist(), true=true.tolist(), relative_error=_json_numbers(error))
    link_part = {link: dict(zip(LINK_PARAMETERS, zip(identified[10 * k:10 * k + 10].tolist(),
                                                     truth[10 * k:10 * k + 10].tolist())))
                 for k, link in enumerate(regressor.links)}
    return dict(joints=joint_part, links=link_part, true=truth.tolist())
