"""An MPC setting per prediction model, chosen on validation plans (`stdm-drake mpc --tune`, the
reality-gap experiment).

A controller's cost is tuned on the robot it drives: the shipped effort weights (controllers/mpc.yaml)
were tuned with the plant model on the robot's description, and on a robot with friction, rotor inertia
and a payload they charge for torque the robot really needs; the offset-free observer helps a model
with a slowly varying bias and hurts one whose error is small and fast-changing (docs/reality_gap.md).
So each prediction model gets the setting it tracks best with from one small grid:

    setting = (effort scale s, observer gain g): the MPC settings with every effort weight times s and
    `disturbance_gain` g, everything else as given.

Rule: the setting with no limit violation on the validation plans and the lowest geometric-mean q MSE
there; if every setting violates, the fewest violations, then the lowest MSE. The test plans are run
only after every choice is made.
"""
import dataclasses
import math

import numpy as np

# (effort-weight scale, observer gain): the grid every model chooses from; SHIPPED: controllers/mpc.yaml
# as it is (its observer gain is 1; the gain of a setting replaces the file's)
MPC_GRID = tuple((scale, gain) for scale in (1.0, 1e-2, 1e-4) for gain in (0.0, 0.3, 1.0))
SHIPPED = (1.0, 1.0)
# a closed loop whose q MSE is not finite (the state left every bound) counts as this q MSE (rad^2)
DIVERGED_Q_MSE = 1e6


def finite_mse(value: float) -> float:
    """A run's q MSE (rad^2) for geometric means: DIVERGED_Q_MSE when it is not finite."""
    return float(value) if math.isfinite(value) else DIVERGED_Q_MSE


def with_setting(config, setting: tuple):
    """The MpcConfig `config` with its effort weights times setting[0] and observer gain setting[1]."""
    scale, gain = setting
    return dataclasses.replace(config, disturbance_gain=float(gain),
                               effort_weight=[float(scale) * float(w) for w in config.effort_weight])


def best_setting(runs_by_setting: dict) -> tuple:
    """The chosen setting of one model: runs_by_setting maps each tried setting to its validation runs
    (each with `q_mse_rad2` and `limit_violations`, as attributes or keys); see the module's rule."""
    def field(run, name):
        return run[name] if isinstance(run, dict) else getattr(run, name)
    scores = []
    for setting, runs in runs_by_setting.items():
        if runs:
            violations = sum(field(run, "limit_violations") for run in runs)
            mse = float(np.exp(np.mean([math.log(finite_mse(field(run, "q_mse_rad2"))) for run in runs])))
            scores.append((violations, mse, tuple(setting)))
    if not scores:
        raise ValueError("no validation runs to choose an MPC setting from")
    return min(scores)[2]


def tune(models: list, references: list, config, plant_config, *, robot, grid=MPC_GRID, progress: bool = False,
         announce=None) -> tuple[dict, list]:
    """Each model's setting from `grid`, chosen on the closed loops of `references` ((index, Reference)
    validation plans) on the plant of `plant_config`: ({model name: setting}, every tuning run as
    (setting, ClosedLoopResult))."""
    from stdm_drake.closed_loop.comparison import compare_controllers   # lazy: pydrake
    tried = []
    for number, setting in enumerate(grid, 1):   # (one bar per setting, titled with it)
        results = compare_controllers(models, references, with_setting(config, setting), plant_config,
                                      progress=progress, robot=robot, announce=announce,
                                      title=f"mpc --tune {number}/{len(grid)}: effort x {setting[0]:g}, gain {setting[1]:g}")
        tried += [(tuple(setting), result) for result in results]
    chosen = {model.name: best_setting({setting: [result for s, result in tried if s == setting and
                                                  result.model == model.name] for setting in grid})
              for model in models}
    return chosen, tried
