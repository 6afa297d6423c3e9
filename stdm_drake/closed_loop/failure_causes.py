"""Why an MPC study's closed loops left the robot's limits, as far as runs can show it (`stdm-drake mpc`'s failure
lines).

Evidence, not a rule of thumb: a plant model of the run (the robot's description, or the affected plant itself) that
held the limits under the same MPC on the same plans makes a failing learned model the cause. Where none held, the
failing plans are run again: with a plant model where the run left it out (`mpc --no-plant`), and, under a sampler
whose ancillary law is not the defaults', with the defaults' law. A plant model holding the limits there names the
learned models, or the law; one failing there too names the MPC's settings, the plans or the plant. (Held-out run 39:
a law inside the defaults' spectral radius whose error changes sign each period, and a learned model run with
`--no-plant`, failed with no cause named; a rule on the law's radius alone had missed the first.)"""
from __future__ import annotations

import dataclasses

from stdm_drake.closed_loop.ancillary_law import law_eigenvalues, law_radius
from stdm_drake.closed_loop.comparison import compare_controllers, failed_steps
from stdm_drake.dynamics.physics import PlantModel

MODEL_CAUSE = ("{evidence}, so this model is not accurate enough for the closed loop (train's one-step verdict is no "
               "closed-loop one)")


@dataclasses.dataclass
class LoopCauses:
    """note: the clause every failing model's line ends with; model_notes: name -> the clause of that model's line."""
    note: str = ""
    model_notes: dict = dataclasses.field(default_factory=dict)


def plants_that_held(results: list, models: list[dict]) -> list[str]:
    """The plant models of the run (`models`' records of kind "plant...") whose loops held the limits on every plan."""
    return [model["name"] for model in models if model["kind"].startswith("plant")
            and not any(result.limit_violations for result in results if result.model == model["name"])]


def model_notes(results: list, models: list[dict]) -> dict:
    """Per learned model, the clause naming it as the cause where a plant model held the limits under the same MPC on
    the same plans (`plants_that_held`; held-out run 38: such lines named nothing); {} where none did."""
    held = plants_that_held(results, models)
    if not held:
        return {}
    evidence = f"the MPC with {plant_phrase(held[0])} held the limits on the same plans"
    return {model["name"]: MODEL_CAUSE.format(evidence=evidence) for model in models
            if not model["kind"].startswith("plant")}


def plant_phrase(name: str) -> str:
    """A plant model's row in a sentence: "the plant model" for the description's ("plant"), else with its row."""
    return "the plant model" if name == "plant" else f"the plant model ({name})"


def law_description(settings, h: float) -> str:
    """The sampler's law (feedback_kp 1/s², feedback_kd 1/s) at the model's period h s, as a phrase: its gains and how
    its held-torque error map (`ancillary_law.check_law_stable`'s) settles against the defaults'."""
    kp, kd = settings.feedback_kp, settings.feedback_kd
    defaults = type(settings)()   # (the settings' own defaults, not restated here)
    dominant = max(law_eigenvalues(kp, kd, h), key=abs)
    sign = ", its error changing sign each period" if dominant.real < 0 else ""
    radius = abs(dominant)
    return (f"the sampler's law (feedback_kp {kp:g} 1/s², feedback_kd {kd:g} 1/s; spectral radius "
            f"{radius:.{3 if radius < 0.9995 else 6}g} of its held-torque error map at the model's period {h:g} s{sign}; the "
            f"defaults' kp {defaults.feedback_kp:g}, kd {defaults.feedback_kd:g}: "
            f"{law_radius(defaults.feedback_kp, defaults.feedback_kd, h):.3g})")


def default_law(optimizer):
    """`optimizer`'s settings with the defaults' law in place of its own; None where it has no law (RTI, iLQR) or
    runs the defaults' already."""
    if not hasattr(optimizer, "feedback_kp"):
        return None
    defaults = type(optimizer)()
    if (optimizer.feedback_kp, optimizer.feedback_kd) == (defaults.feedback_kp, defaults.feedback_kd):
        return None
    return dataclasses.replace(optimizer, feedback_kp=defaults.feedback_kp, feedback_kd=defaults.feedback_kd)


def check_model(plant_config, sample_period: float, robot) -> PlantModel:
    """The plant model a check runs (as `mpc`'s plant rows): the affected plant where its effects are all rigid-body
    ones (the RK4 model holds them), else the robot's description."""
    effects = plant_config.effects if plant_config is not None else None
    if effects is not None and not effects.beyond_rigid_bodies():
        return PlantModel(sample_period, plant_config, robot=robot, integrator="rk4")
    return PlantModel(sample_period, robot=robot, integrator="rk4")


def loop_causes(results: list, models: list[dict], references: list, config, plant_config, robot,
                sample_period: float, gravity: str = "", effects: str = "", say=None,
                learned_models: list = ()) -> LoopCauses:
    """The causes of the failing loops of `results` (`ClosedLoopResult`s of the models `models` records, kind "plant..."
    for plant models) on `references` ((index, Reference) pairs) under `config` (MpcConfig) on `plant_config`'s plant
    at `sample_period` s. gravity: the clause naming an effort limit below gravity on the plans (then the whole
    cause); effects: the clause naming the plant effects that shape the loops; say: called with one line before a
    check runs (None: quiet); learned_models: the learned models of the run (`.name`), each checked under the defaults'
    law where the law is found to make the plant model's loops fail (held-out run 40: a poor model under a ringing
    law was named by the law alone, and left the limits under the defaults' law too)."""
    failing = sorted({result.trajectory for result in results if failed_steps([result])})
    if not failing:
        return LoopCauses()
    notes = model_notes(results, models)
    if notes or gravity:
        return LoopCauses(gravity or effects, notes)
    plans = [(index, reference) for index, reference in references if index in failing]
    learned = [model["name"] for model in models if not model["kind"].startswith("plant")]
    checked, law = [], default_law(config.optimizer)
    plant_ran = any(record["kind"].startswith("plant") for record in models)
    model = check_model(plant_config, sample_period, robot) if law is not None or not plant_ran else None   # (checks)
    if not plant_ran:   # (--no-plant)
        steps = _failed_steps(model, plans, config, plant_config, robot, say, "the same MPC with the plant model")
        if not steps:
            evidence = (f"the same MPC with {plant_phrase(model.name)} held the limits on these plans (a check run "
                        "once the loops had failed)")
            return LoopCauses(effects, {name: MODEL_CAUSE.format(evidence=evidence) for name in learned})
        checked.append(f"the same MPC with {plant_phrase(model.name)} left the limits too ({steps} steps, a check run "
                       "once the loops had failed)")
    if law is not None:
        steps = _failed_steps(model, plans, dataclasses.replace(config, optimizer=law), plant_config, robot, say,
                              "the plant model under the defaults' law")
        description = law_description(config.optimizer, sample_period)
        if not steps:
            evidence = ("under the defaults' law too this model's loops failed where the plant model held the limits (a "
                        "check run once the loops had failed)")
            notes = {learned_model.name: MODEL_CAUSE.format(evidence=evidence) for learned_model in learned_models
                     if failed_steps([result for result in results if result.model == learned_model.name])
                     and _failed_steps(learned_model, plans, dataclasses.replace(config, optimizer=law), plant_config,
                                       robot, say, f"model {learned_model.name} under the defaults' law")}
            return LoopCauses("; ".join(filter(None, [
                f"{description} makes the loops leave the robot's limits: under the defaults' law the same MPC with "
                f"{plant_phrase(model.name)} held them on these plans; use the defaults, or gains that settle like them",
                effects])), notes)
        checked.append(f"{plant_phrase(model.name)} left the limits under the defaults' law too, not only under "
                       f"{description}")
    if not checked and not learned:   # (only plant models ran, and failed: the effects, else the MPC or the plans)
        return LoopCauses(effects or "with the robot's own dynamics as the MPC's model: the MPC's settings (--config) or "
                                     "the plans are why")
    evidence = " and ".join(checked) or "the plant model's own loops left the limits too under this MPC"
    return LoopCauses("; ".join(filter(None, [effects, f"{evidence}, so the MPC's settings (--config), the plans or "
                                                       "the plant are why, not a learned model's accuracy"])))


def _failed_steps(model, plans: list, config, plant_config, robot, say, what: str) -> int:
    """`failed_steps` of `model`'s loops under `config` on `plans` (a check, not recorded)."""
    if say is not None:
        say(f"the loops failed: running {what} on the {len(plans)} failing plans to name the cause")
    return failed_steps(compare_controllers([model], plans, config, plant_config, progress=False, robot=robot))
