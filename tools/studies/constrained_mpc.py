"""The robot's limits inside the MPC: clipping against constraints on the UR-10 and the Panda where limits bind.

The design is docs/constrained_mpc.md (committed before any run): per robot, data and the default model
(`collect`, `train`), then the plant and the default model as prediction models under the MPC with
`constraints: {mode: off}` (clip, the controller before constraints) and with the default constraints, on 8
held-out plans, 8 plans that end a few degrees inside a position limit, the same with a payload beyond the effort
limits and with a push toward the limit; per cell the paired ratios over plans with their 95 % intervals, the
crossings of the plant's limits and the verdicts the design fixes.

    python tools/study.py constrained-mpc [--run 3] [--quick] [-o docs/results/constrained_mpc/run3] [--data out/constrained_mpc_data]

Run 1 is the first design (default tracking data, the payload 1.25x the static limit, a push toward the limit);
run 2 the second (identification data, a holdable payload beyond the limits while accelerating, a push away from
a goal near a limit); run 3 (the default) the third (run 2's data and models; plans that leave a position limit
or exceed a velocity limit); all in docs/constrained_mpc.md. Data and trained models are kept in --data, so a
second run only repeats the closed loops.
"""
import argparse
import dataclasses
import json
import math
import os
import pathlib
import sys
import time

for _variable in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):   # one thread (before numpy loads:
    os.environ.setdefault(_variable, "1")                                         # the launcher imports this first)

import numpy as np  # noqa: E402

ROOT = pathlib.Path(__file__).resolve().parents[2]
ROBOTS = ("ur10", "panda")
SCENARIOS = {1: ("held-out", "near-limit", "payload", "push"), 2: ("held-out", "near-limit", "payload", "push"),
             3: ("past-limit", "over-speed")}
BINDING = ("near-limit", "payload", "push", "past-limit", "over-speed")   # the scenarios with a limits verdict
OVER_SPEED = 1.5             # run 3: the over-speed move's duration is the near-limit one's over this
ARMS = ("clip", "constrained")
FULL = dict(count=30, plans=8, epochs=150, split=(4, 1, 2))
QUICK = dict(count=12, plans=2, epochs=3, split=(1, 1, 1))
HOLD_S = 0.5                 # the near-limit plans hold their goal this long after the move
PUSH_S = 0.1                 # the push's duration (run 1)
PUSH_AWAY_S = 0.01           # run 2's push: one control period
TRACKING_MARGIN = 1.05       # "no worse": the tracking ratio's upper end at most this
SOLVE_GOAL = 1.5             # "within 1.5x": the solve-time ratio's upper end at most this


# -- data, model, plans ------------------------------------------------------------------------------------------

def prepare(robot_name: str, folder: pathlib.Path, profile: dict, say, design: int) -> dict:
    """The robot's tracking data (run 2: identification data, dithered PID and an ideal sensor) and default model
    (kept in `folder`): paths and the model's training verdict."""
    from stdm_drake.collection.collect_job import CollectJob, collect_job
    from stdm_drake.learning.settings import TrainSettings
    from stdm_drake.learning.train_job import TrainJob, train_job
    from stdm_drake.paths import CONTROLLERS_DIR, MODELS_DIR
    folder.mkdir(parents=True, exist_ok=True)
    robot_path = MODELS_DIR / f"{robot_name}.yaml"
    data = folder / "tracking.h5"
    if not data.exists():
        say(f"{robot_name}: collect {profile['count']} tracking plans")
        recipe = (dict(controller=CONTROLLERS_DIR / "pid_dither_sized.yaml", sensor=CONTROLLERS_DIR / "sensor_ideal.yaml")
                  if design == 2 else {})
        collect_job(CollectJob(output=data, protocol="tracking", count=profile["count"], seed=0, robot=robot_path,
                               workers=1, progress=False, **recipe))
    checkpoint = folder / "default" / "seed0" / "checkpoint.pt"
    if not checkpoint.exists():
        say(f"{robot_name}: train the default model")
        train, val, test = profile["split"]
        given = dict(seeds=[0], train=train, val=val, test=test, epochs=profile["epochs"])
        train_job(TrainJob(dataset=data, output=folder / "default", settings=TrainSettings(**given), robot=robot_path,
                           progress=False, given=frozenset(given)))
    summary = json.loads((folder / "default" / "summary.json").read_text())
    return dict(robot=robot_path, data=data, checkpoint=checkpoint, training=training_verdict(summary))


def training_verdict(summary: dict) -> dict:
    """The default model's validation verdict against the physics baselines, as `train` printed it."""
    entry = next(iter(summary["seeds"].values())) if isinstance(summary["seeds"], dict) else summary["seeds"][0]
    row = entry["validation"]["models"][0]
    return dict(name=row["name"], verdict=row["verdict"], ratio_q=row["ratio_to_euler_q"],
                ratio_v=row["ratio_to_velocity_unchanged_v"])


def quintic(start: np.ndarray, goal: np.ndarray, steps: int, period: float, hold: int):
    """q, v (steps + hold + 1, n): a rest-to-rest quintic from start to goal in `steps` periods, then the goal held."""
    tau = np.linspace(0.0, 1.0, steps + 1)[:, None]
    s = 10 * tau ** 3 - 15 * tau ** 4 + 6 * tau ** 5
    ds = (30 * tau ** 2 - 60 * tau ** 3 + 30 * tau ** 4) / (steps * period)
    q = np.vstack([start + (goal - start) * s, np.repeat(goal[None], hold, axis=0)])
    v = np.vstack([(goal - start) * ds, np.zeros((hold, len(start)))])
    return q, v


def near_limit_plans(robot, count: int, period: float) -> list[dict]:
    """The design's near-limit plans: joint j's goal 2-5 degrees inside a drawn limit, its peak velocity 80 % of its
    limit, the other joints near home; start and goal (and 9 points between) free of self-collision."""
    from stdm_drake.robots.plant import SelfCollisionChecker, robot_joint_limits
    limits = robot_joint_limits(robot)
    checker = SelfCollisionChecker(robot)
    home = np.asarray(robot.home, dtype=float)
    n = len(home)
    plans = []
    for plan in range(count):
        rng = np.random.default_rng(1000 + plan)
        for draw in range(1, 201):
            joint, side = int(rng.integers(n)), int(rng.choice([-1, 1]))
            limit = limits.position_upper[joint] if side > 0 else limits.position_lower[joint]
            inside, travel = math.radians(rng.uniform(2.0, 5.0)), rng.uniform(0.3, 0.8)
            start, goal = home + rng.uniform(-0.2, 0.2, n), home + rng.uniform(-0.2, 0.2, n)
            if not np.isfinite(limit):
                continue
            goal[joint] = limit - side * inside
            start[joint] = goal[joint] - side * travel
            within = [np.all(q > limits.position_lower + 0.01) and np.all(q < limits.position_upper - 0.01)
                      for q in (start, goal)]
            if not all(within):
                continue
            path = [start + (goal - start) * s for s in np.linspace(0.0, 1.0, 11)]
            if all(checker.is_collision_free(q) for q in path):
                break
        else:
            raise RuntimeError(f"near-limit plan {plan}: no collision-free draw in 200")
        duration = max(0.3, float(np.max(1.875 * np.abs(goal - start) / (0.8 * limits.velocity))))
        steps = int(math.ceil(duration / period - 1e-9))
        plans.append(dict(plan=plan, draws=draw, joint=joint, joint_name=robot.joint_names[joint], side=side,
                          inside_rad=inside, travel_rad=travel, start=start.tolist(), goal=goal.tolist(),
                          move_steps=steps, hold_steps=int(round(HOLD_S / period))))
    return plans


def smallest_exceeding_mass(effort: np.ndarray, torques) -> float:
    """The least point mass m > 0 at the tool for which some |tau0_j + m per_kg_j| exceeds effort_j (N m), over
    the (tau0 (n,), per_kg (n,)) pairs of `torques` (a torque linear in the payload's mass); inf if none."""
    low = np.inf
    for tau0, per_kg in torques:
        for j in range(len(tau0)):
            if abs(per_kg[j]) < 1e-9:
                continue
            bound = (effort[j] - tau0[j]) / per_kg[j] if per_kg[j] > 0 else (-effort[j] - tau0[j]) / per_kg[j]
            if bound > 0:
                low = min(low, bound)
    return float(low)


def static_torques(robot, q: np.ndarray) -> list:
    """(gravity torque, its change per kg at the tool) at every pose of q (T, n)."""
    from stdm_drake.robots.effects import Payload, PlantEffects
    from stdm_drake.robots.plant import Dynamics
    bare, loaded = Dynamics(robot), Dynamics(robot, PlantEffects(payload=Payload(mass=1.0)))
    return [(bare.gravity_torque(pose), loaded.gravity_torque(pose) - bare.gravity_torque(pose)) for pose in q]


def payload_mass(robot, q: np.ndarray) -> float:
    """1.25 x the smallest point mass at the tool whose static gravity torque at some pose of q (T, n) exceeds some
    joint's effort limit (run 1's payload)."""
    from stdm_drake.robots.plant import robot_joint_limits
    return 1.25 * smallest_exceeding_mass(robot_joint_limits(robot).effort, static_torques(robot, q))


def holdable_payload(robot, q: np.ndarray, v: np.ndarray, period: float) -> dict:
    """Run 2's payload on a plan q, v (T, n): halfway between m_dyn (the smallest point mass at the tool whose
    inverse-dynamics torque along the plan exceeds some joint's effort limit) and m_static (whose static gravity
    torque at some pose does); 0.9 m_static, marked "no dynamic excess", where m_dyn >= m_static."""
    from stdm_drake.robots.effects import Payload, PlantEffects
    from stdm_drake.robots.plant import Dynamics, robot_joint_limits
    effort = robot_joint_limits(robot).effort
    bare, loaded = Dynamics(robot), Dynamics(robot, PlantEffects(payload=Payload(mass=1.0)))
    acceleration = np.gradient(v, period, axis=0)

    def demand(dynamics, pose, velocity, qdd):       # M(q) (q̈ - a(q, v, 0)): the torque that gives q̈
        return dynamics.mass_matrix(pose) @ (qdd - dynamics.acceleration(pose, velocity, np.zeros(len(pose))))
    static = smallest_exceeding_mass(effort, static_torques(robot, q))
    dynamic = smallest_exceeding_mass(effort, [
        (demand(bare, pose, velocity, qdd), demand(loaded, pose, velocity, qdd) - demand(bare, pose, velocity, qdd))
        for pose, velocity, qdd in zip(q, v, acceleration)])
    excess = dynamic < static
    return dict(payload_kg=0.5 * (dynamic + static) if excess else 0.9 * static, m_dynamic_kg=dynamic,
                m_static_kg=static, dynamic_excess=bool(excess))


def push_away(robot, plan: dict, period: float) -> dict:
    """Run 2's push on a near-limit plan: joint j away from its limit, from the move's end for PUSH_AWAY_S, of
    M_eff,j(goal) x 0.8 v_max,j / PUSH_AWAY_S (staying inside is possible on every plan: the return may be slow)."""
    from stdm_drake.robots.plant import Dynamics, robot_joint_limits
    limits, dynamics = robot_joint_limits(robot), Dynamics(robot)
    goal, j = np.asarray(plan["goal"]), plan["joint"]
    inertia = float(dynamics.effective_inertia(goal)[j])
    force = inertia * 0.8 * limits.velocity[j] / PUSH_AWAY_S
    return dict(torque_nm=float(-plan["side"] * force), start_s=plan["move_steps"] * period, duration_s=PUSH_AWAY_S,
                effective_inertia=inertia, possible=True)


def push_of(robot, plan: dict, period: float) -> dict:
    """The design's push on a near-limit plan (joint j toward its limit, from the move's end for PUSH_S) and its
    feasibility estimate (the joint's travel under full braking against the distance to its limit)."""
    from stdm_drake.robots.plant import Dynamics, robot_joint_limits
    limits, dynamics = robot_joint_limits(robot), Dynamics(robot)
    goal, j = np.asarray(plan["goal"]), plan["joint"]
    inertia = float(dynamics.effective_inertia(goal)[j])
    force = inertia * 0.5 * limits.velocity[j] / PUSH_S
    braking = float(limits.effort[j] - abs(dynamics.gravity_torque(goal)[j]))
    if braking <= 0:
        travel = np.inf
    else:
        push_acceleration = max(force - braking, 0.0) / inertia
        speed = push_acceleration * PUSH_S
        travel = 0.5 * push_acceleration * PUSH_S ** 2 + speed ** 2 / (2 * braking / inertia)
    return dict(torque_nm=float(plan["side"] * force), start_s=plan["move_steps"] * period, duration_s=PUSH_S,
                effective_inertia=inertia, braking_nm=braking, travel_rad=float(travel),
                distance_rad=float(plan["inside_rad"]), possible=bool(travel < plan["inside_rad"]))


# -- closed loops ------------------------------------------------------------------------------------------------

def crossing_depth(states: np.ndarray, limits) -> float:
    """The deepest crossing of the plant's position or velocity limits over a loop's states (rad or rad/s; 0: none,
    inf: a state not finite)."""
    n = len(limits.velocity)
    if not np.all(np.isfinite(states)):
        return float("inf")
    q, v = states[:, :n], states[:, n:]
    depth = np.concatenate([(q - limits.position_upper).ravel(), (limits.position_lower - q).ravel(),
                            (np.abs(v) - limits.velocity).ravel()])
    return float(max(depth.max(), 0.0))


def run_cell_loops(robot, prepared: dict, profile: dict, say, design: int) -> dict:
    """Every closed loop of one robot under design `design` (1 or 2): (runs, the plans' records)."""
    import torch

    from stdm_drake.closed_loop.comparison import closed_loop_metrics, held_out_references
    from stdm_drake.closed_loop.constraints import Constraints
    from stdm_drake.closed_loop.mpc import Reference, mpc_config_for, run_closed_loop
    from stdm_drake.closed_loop.push import JointPush
    from stdm_drake.data.dataset import load_dataset
    from stdm_drake.dynamics.model_files import load_model
    from stdm_drake.dynamics.physics import PlantModel
    from stdm_drake.learning.checkpoint import load_checkpoint
    from stdm_drake.robots.effects import Payload, PlantEffects
    from stdm_drake.robots.plant import DEFAULT_PLANT_TIME_STEP, Dynamics, PlantConfig, robot_joint_limits
    from stdm_drake.robots.plant_effects_check import plant_effects_for
    torch.set_num_threads(1)
    data = load_dataset(prepared["data"])
    period = data.sample_period
    time_step = data.metadata.plant_time_step or DEFAULT_PLANT_TIME_STEP
    limits, dynamics = robot_joint_limits(robot), Dynamics(robot)
    n = len(limits.velocity)
    checkpoint = load_checkpoint(prepared["checkpoint"])
    held_out = held_out_references(data, [checkpoint], profile["plans"])
    near = near_limit_plans(robot, profile["plans"], period)
    references = {"held-out": [(index, reference, dict(plan=index)) for index, reference in held_out]}
    references["near-limit"] = [(plan["plan"], Reference(*quintic(np.asarray(plan["start"]), np.asarray(plan["goal"]),
                                                                  plan["move_steps"], period, plan["hold_steps"])),
                                 plan) for plan in near]
    nominal = PlantConfig.discrete(time_step)
    plants, pushes = {}, {}
    for index, reference, plan in (references["near-limit"] if "payload" in SCENARIOS[design] else []):
        if design == 2:
            plan["payload"] = holdable_payload(robot, reference.q, reference.v, period)
            mass = plan["payload_kg"] = plan["payload"]["payload_kg"]
        else:
            mass = plan["payload_kg"] = payload_mass(robot, reference.q)
        plants[index] = PlantConfig.discrete(time_step, effects=plant_effects_for(
            PlantEffects(source="constrained-mpc study: a payload the models do not know",
                         payload=Payload(mass=mass)), robot, time_step))
        plan["push"] = push_away(robot, plan, period) if design == 2 else push_of(robot, plan, period)
        torque = np.zeros(n)
        torque[plan["joint"]] = plan["push"]["torque_nm"]
        pushes[index] = JointPush(torque, plan["push"]["start_s"], plan["push"]["duration_s"])
    references["payload"] = references["push"] = references["near-limit"]
    references["past-limit"], references["over-speed"] = [], []
    for plan in near:      # run 3: the goal mirrored across the limit; the move 1/OVER_SPEED as long
        start, goal = np.asarray(plan["start"]), np.asarray(plan["goal"])
        beyond = goal.copy()
        beyond[plan["joint"]] += 2 * plan["side"] * plan["inside_rad"]
        references["past-limit"].append((plan["plan"], Reference(*quintic(start, beyond, plan["move_steps"], period,
                                                                          plan["hold_steps"])), plan))
        fast = max(1, int(round(plan["move_steps"] / OVER_SPEED)))
        plan["over_speed_peak_ratio"] = float(1.875 * abs(goal - start)[plan["joint"]] / (fast * period)
                                              / limits.velocity[plan["joint"]])
        references["over-speed"].append((plan["plan"], Reference(*quintic(start, goal, fast, period, plan["hold_steps"])),
                                         plan))
    models = [PlantModel(period, robot=robot, integrator="rk4"),
              load_model(prepared["checkpoint"], robot, name="default", for_control=True)]
    config = mpc_config_for(robot)
    configs = {"clip": dataclasses.replace(config, constraints=Constraints(mode="off")), "constrained": config}
    runs = []
    total = len(SCENARIOS[design]) * profile["plans"] * len(models) * len(ARMS)
    started = time.perf_counter()
    for scenario in SCENARIOS[design]:
        for index, reference, plan in references[scenario]:
            gravity = np.array([dynamics.gravity_torque(q) for q in reference.window(0, len(reference.q) + 1)[:, :n]])
            for model in models:
                for arm in ARMS:
                    log = run_closed_loop(model, reference, configs[arm],
                                          plants[index] if scenario == "payload" else nominal, robot=robot,
                                          push=pushes[index] if scenario == "push" else None)
                    metrics = closed_loop_metrics(model.name, index, log, reference, limits, gravity)
                    states = np.array(log.state)
                    runs.append(dict(robot=robot.name, scenario=scenario, plan=index, model=model.name, arm=arm,
                                     q_rms_rad=float(math.sqrt(metrics.q_mse_rad2)),
                                     crossing_steps=metrics.limit_violations,
                                     crossing_depth=crossing_depth(states, limits),
                                     solve_ms_mean=metrics.solve_ms_mean, solve_ms_p95=metrics.solve_ms_p95,
                                     constraint_active_steps=metrics.constraint_active_steps,
                                     slack_steps=metrics.slack_steps, fallbacks=metrics.fallbacks,
                                     steps=metrics.steps))
            done = sum(1 for run in runs if run["robot"] == robot.name)
            say(f"{robot.name}: {scenario} plan {index}: {done} of {total} loops, "
                f"{time.perf_counter() - started:.0f} s")
    plans = dict(held_out=[plan for _, _, plan in references["held-out"]], near_limit=near)
    return dict(runs=runs, plans=plans, mpc_settings=config.record())


# -- analysis ----------------------------------------------------------------------------------------------------

def paired_ratio(numerator: list, denominator: list) -> dict:
    """Geometric mean of numerator / denominator over plans with a Student-t 95 % interval on the log ratios."""
    from scipy import stats
    logs = np.log(np.asarray(numerator, dtype=float) / np.asarray(denominator, dtype=float))
    mean = float(logs.mean())
    half = float(stats.t.ppf(0.975, len(logs) - 1) * logs.std(ddof=1) / math.sqrt(len(logs))) if len(logs) > 1 else np.inf
    return dict(ratio=math.exp(mean), low=math.exp(mean - half), high=math.exp(mean + half), plans=len(logs))


def tracking_verdict(interval: dict) -> str:
    if interval["high"] < 1.0:
        return "constrained better"
    if interval["high"] <= TRACKING_MARGIN:
        return "no worse"
    if interval["low"] > TRACKING_MARGIN:
        return "constrained worse"
    return "inconclusive"


def solve_verdict(interval: dict) -> str:
    if interval["high"] <= SOLVE_GOAL:
        return "within 1.5x"
    if interval["low"] > SOLVE_GOAL:
        return "beyond 1.5x"
    return "inconclusive"


def cells(runs: list, plans: dict) -> list:
    """One cell per robot x model x scenario: the paired ratios, the crossing plans and the design's verdicts."""
    out = []
    keys = dict.fromkeys((run["robot"], run["model"], run["scenario"]) for run in runs)
    for robot, model, scenario in keys:
        mine = [run for run in runs if (run["robot"], run["model"], run["scenario"]) == (robot, model, scenario)]
        by = {(run["plan"], run["arm"]): run for run in mine}
        indices = sorted({run["plan"] for run in mine})
        clip, constrained = [by[(i, "clip")] for i in indices], [by[(i, "constrained")] for i in indices]
        floor = 1e-12     # (an RMS of exactly zero would have no logarithm)
        tracking = paired_ratio([max(r["q_rms_rad"], floor) if np.isfinite(r["q_rms_rad"]) else 1e6 for r in constrained],
                                [max(r["q_rms_rad"], floor) if np.isfinite(r["q_rms_rad"]) else 1e6 for r in clip])
        solve = paired_ratio([r["solve_ms_mean"] for r in constrained], [r["solve_ms_mean"] for r in clip])
        clip_cross = [i for i, r in zip(indices, clip) if r["crossing_steps"]]
        constrained_cross = [i for i, r in zip(indices, constrained) if r["crossing_steps"]]
        impossible = []
        if scenario == "push":
            impossible = [plan["plan"] for plan in plans[robot]["near_limit"] if not plan["push"]["possible"]]
        cell = dict(robot=robot, model=model, scenario=scenario, tracking=tracking,
                    tracking_verdict=tracking_verdict(tracking), solve=solve, solve_verdict=solve_verdict(solve),
                    clip_crossing_plans=clip_cross, constrained_crossing_plans=constrained_cross,
                    impossible_plans=impossible,
                    clip_crossing_steps=int(sum(r["crossing_steps"] for r in clip)),
                    constrained_crossing_steps=int(sum(r["crossing_steps"] for r in constrained)),
                    clip_deepest=float(max(r["crossing_depth"] for r in clip)),
                    constrained_deepest=float(max(r["crossing_depth"] for r in constrained)),
                    constraint_active_steps=int(sum(r["constraint_active_steps"] for r in constrained)),
                    slack_steps=int(sum(r["slack_steps"] for r in constrained)),
                    steps=int(sum(r["steps"] for r in constrained)),
                    fallbacks=dict(clip=int(sum(r["fallbacks"] for r in clip)),
                                   constrained=int(sum(r["fallbacks"] for r in constrained))))
        if scenario in BINDING:
            failed = [i for i in clip_cross if i in constrained_cross and i not in impossible]
            introduced = [i for i in constrained_cross if i not in clip_cross]
            if failed or introduced:
                cell["limits_verdict"] = "not met"
            elif not clip_cross:
                cell["limits_verdict"] = "nothing to prevent"
            else:
                cell["limits_verdict"] = "met"
            cell["limits_failed_plans"], cell["limits_introduced_plans"] = failed, introduced
        out.append(cell)
    return out


def goals(table: list) -> dict:
    """The issue's goals as the design states them (run 3: its own answer, `run3_answer`)."""
    binding = [cell for cell in table if cell["scenario"] in BINDING]
    held = [cell for cell in table if cell["scenario"] == "held-out"]
    failing_a = [f"{c['robot']} {c['model']} {c['scenario']}" for c in binding if c["limits_verdict"] == "not met"]
    failing_b = [f"{c['robot']} {c['model']}: tracking {c['tracking_verdict']}, solve {c['solve_verdict']}" for c in held
                 if c["tracking_verdict"] not in ("no worse", "constrained better") or c["solve_verdict"] != "within 1.5x"]
    if not held:     # run 3: no held-out plans; its answer instead of goal (b)
        return dict(limits=dict(verdict="met" if not failing_a else "not met", failing=failing_a),
                    run3_answer=run3_answer(binding))
    return dict(limits=dict(verdict="met" if not failing_a else "not met", failing=failing_a),
                nothing_binds=dict(verdict="met" if not failing_b else "not met", failing=failing_b))


def run3_answer(cells_: list) -> str:
    """Run 3's answer (docs/constrained_mpc.md): "yes" when every plant cell is met and no cell is not met."""
    plant = [cell for cell in cells_ if cell["model"] == "plant"]
    failing = [cell for cell in cells_ if cell["limits_verdict"] == "not met"]
    if all(cell["limits_verdict"] == "met" for cell in plant) and not failing:
        return "yes"
    if all(cell["limits_verdict"] == "met" for cell in plant) and all(cell["model"] != "plant" for cell in failing):
        return "yes with the plant, not with the default model"
    return "no"


# -- output ------------------------------------------------------------------------------------------------------

def lines_of(table: list, goal: dict, training: dict) -> list[str]:
    text = []
    for robot, verdict in training.items():
        text.append(f"{robot}: default model's training verdict: {verdict.get('verdict')} (validation one-step q "
                    f"{verdict.get('ratio_q', float('nan')):.3g}x, v {verdict.get('ratio_v', float('nan')):.3g}x the "
                    "physics-free baselines)")
    for cell in table:
        t, s = cell["tracking"], cell["solve"]
        limits = (f"; limits {cell['limits_verdict']}" if "limits_verdict" in cell else "")
        text.append(f"{cell['robot']} {cell['model']} {cell['scenario']}: tracking constrained/clip {t['ratio']:.3g}x "
                    f"[{t['low']:.3g}, {t['high']:.3g}] ({cell['tracking_verdict']}); solve {s['ratio']:.3g}x "
                    f"[{s['low']:.3g}, {s['high']:.3g}] ({cell['solve_verdict']}); plans crossing a limit: clip "
                    f"{cell['clip_crossing_plans']}, constrained {cell['constrained_crossing_plans']}"
                    + (f", impossible {cell['impossible_plans']}" if cell["impossible_plans"] else "")
                    + f"; deepest clip {cell['clip_deepest']:.3g}, constrained {cell['constrained_deepest']:.3g}"
                    + f"; constraint active {cell['constraint_active_steps']}/{cell['steps']} steps, slack "
                    f"{cell['slack_steps']}{limits}")
    text.append(f"goal (a), no limit crossed where clipping crosses: {goal['limits']['verdict']}"
                + (f" ({'; '.join(goal['limits']['failing'])})" if goal["limits"]["failing"] else ""))
    if "run3_answer" in goal:
        text.append(f"run 3's answer, the constrained controller keeps the limits a plan leaves: {goal['run3_answer']}")
        return text
    text.append(f"goal (b), where nothing binds tracking no worse and solve within 1.5x: {goal['nothing_binds']['verdict']}"
                + (f" ({'; '.join(goal['nothing_binds']['failing'])})" if goal["nothing_binds"]["failing"] else ""))
    return text


def write_results(results: dict, folder: pathlib.Path) -> None:
    from stdm_drake.files import write_text_atomic
    folder.mkdir(parents=True, exist_ok=True)
    write_text_atomic(folder / "results.json", json.dumps(results, indent=1, default=float))
    columns = list(results["runs"][0])
    write_text_atomic(folder / "runs.csv", "\n".join([",".join(columns)] + [
        ",".join(str(run[column]) for column in columns) for run in results["runs"]]) + "\n")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--run", type=int, choices=(1, 2, 3), default=3,
                        help="the design (docs/constrained_mpc.md): 1 (the first), 2 (after run 1's results), 3 (plans "
                             "that leave a limit, after run 2's; the default)")
    parser.add_argument("--quick", action="store_true",
                        help="2 plans per scenario, 12 plans of data, 3 epochs (a smoke run; out/constrained_mpc_quick)")
    parser.add_argument("--output", "-o", type=pathlib.Path,
                        help="results folder (default docs/results/constrained_mpc; --quick: out/constrained_mpc_quick)")
    parser.add_argument("--data", type=pathlib.Path,
                        help="data and models, kept between runs (default out/constrained_mpc_data[_quick])")
    parser.add_argument("--robots", nargs="+", choices=ROBOTS, default=list(ROBOTS), help="robots (default both)")


def run(args: argparse.Namespace) -> int:
    from stdm_drake.robots.robot import load_robot
    profile = QUICK if args.quick else FULL
    suffix = "_quick" if args.quick else ""
    results_folder = ROOT / "docs" / "results" / "constrained_mpc"
    output = args.output or (ROOT / "out" / "constrained_mpc_quick" if args.quick
                             else results_folder / f"run{args.run}" if args.run > 1 else results_folder)
    # (run 3 uses run 2's data and models)
    data_folder = (args.data or ROOT / "out" / f"constrained_mpc_data{suffix}") / ("run2" if args.run > 1 else "")

    def say(line: str) -> None:
        print(line, file=sys.stderr, flush=True)
    started = time.perf_counter()
    runs, plans, training, settings = [], {}, {}, {}
    for name in args.robots:
        prepared = prepare(name, data_folder / name, profile, say, min(args.run, 2))
        robot = load_robot(prepared["robot"])
        training[robot.name] = prepared["training"]
        result = run_cell_loops(robot, prepared, profile, say, args.run)
        runs += result["runs"]
        plans[robot.name] = result["plans"]
        settings[robot.name] = result["mpc_settings"]
    table = cells(runs, plans)
    goal = goals(table)
    text = lines_of(table, goal, training)
    print("\n".join(text))
    results = dict(written_by="tools/study.py constrained-mpc", design="docs/constrained_mpc.md", run=args.run,
                   quick=args.quick,
                   provenance=args.provenance, seconds=round(time.perf_counter() - started, 1), profile=profile,
                   training=training, mpc_settings=settings, plans=plans, cells=table, goals=goal, summary=text,
                   runs=runs)
    write_results(results, output)
    print(f"wrote {output}: results.json, runs.csv")
    return 0
