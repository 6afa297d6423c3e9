"""Why the RL loop's last round left the robot's limits, as far as the run can show it (`stdm-drake mbrl`'s failure
line): gravity beyond an effort limit, a model `train` judged unlearned, or, for a model judged learned, what the
same MPC did with the robot's description as its model on the same plans (held-out run 37: such loops failed with
no cause named)."""
from __future__ import annotations

from stdm_drake.dynamics.physics import PlantModel


def description_model_loops(config, references: list, station) -> dict:
    """The loop's MPC with the robot's description as its model (the RK4 plant model, `dynamics.physics.PlantModel`)
    on the evaluation references, on the loop's plant (`station`'s): its steps outside the limits, and the plant
    effects that shape the loops (`robots.station.loop_effects` phrases). Within the limits there, the learned model
    is why the loops failed; outside them too, the loop itself (the MPC's settings, the plant)."""
    from stdm_drake.closed_loop.comparison import compare_controllers   # lazy: pydrake
    from stdm_drake.robots.station import loop_effects   # lazy: pydrake
    model = PlantModel(station.settings.sample_period, robot=config.robot, integrator="rk4")
    results = compare_controllers([model], references, config.mpc, station.settings.plant, progress=False,
                                  robot=config.robot)
    return dict(steps_outside_limits=int(sum(result.limit_violations for result in results)),
                steps=int(sum(result.steps for result in results)),
                plant_effects=loop_effects(station.settings.plant.effects, list(config.robot.joint_names)))


def failure_line(last: dict) -> str:
    """The failure line (after "stdm-drake mbrl: error: ") of the loop's last round (its summary.json row), naming
    each cause the run recorded."""
    from stdm_drake.learning.evaluate import times_better   # lazy: torch
    verdict = last.get("learned") or {}
    ratios = (f"validation: one-step q {times_better(verdict['ratio_q'])}, v {times_better(verdict['ratio_v'])} "
              "than the physics-free steps; learned is 2x better in both" if "ratio_q" in verdict and
              "ratio_v" in verdict else "train's validation verdict")
    causes = [last.get("gravity", "")] + ([
        f"its model has not learned the dynamics ({ratios}): more plans (--initial-plans, --plans-per-round) or "
        "epochs (--epochs)"] if verdict.get("verdict") and not str(verdict["verdict"]).startswith("learned") else [])
    causes += [description_model_cause(last["description_model"])] if "description_model" in last else []
    return (f"the last round's closed loops left the robot's limits on {last['steps_outside_limits']} steps"
            + "".join(f"; {cause}" for cause in causes if cause))


def description_model_cause(loops: dict) -> str:
    """What the same MPC with the robot's description as its model did on the evaluation plans (`mbrl_loop.
    description_model_loops`), as the failure line's cause."""
    effects = f"; the loops ran with {', '.join(loops['plant_effects'])}" if loops["plant_effects"] else ""
    if not loops["steps_outside_limits"]:
        return ("the same MPC with the robot's description as its model held the limits on these plans, so the last "
                "model is not yet accurate enough for the closed loop (train's one-step verdict is no closed-loop "
                "one): more plans (--initial-plans, --plans-per-round), rounds (--rounds) or epochs (--epochs)"
                + effects)
    return (f"the same MPC with the robot's description as its model left them too ({loops['steps_outside_limits']} "
            f"of {loops['steps']} steps): the MPC's settings (--config) or the plant, not the model alone" + effects)
