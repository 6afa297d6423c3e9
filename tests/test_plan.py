"""Planners of the tracked task-space protocol: IK, quintic/ruckig/toppra boundary conditions and
limits, rejection + resampling, and the tracking spec YAML."""
import dataclasses
import time

import numpy as np
import pytest
import ruckig
from pydrake.math import RigidTransform, RotationMatrix

from presets import UR10
from stdm_drake.errors import InputError, PlanningError
from stdm_drake.robots.kinematics import RobotKinematics, rotation_exp, rotation_log
from stdm_drake.collection.plan import InitialPose, TaskSpaceSamplingConfig, initial_configuration, sample_task_plans
from stdm_drake.collection.protocols import load_tracking_spec
from stdm_drake.collection.planner_configs import PLANNER_KINDS, PlannerConfig, Quintic, Ruckig
from stdm_drake.collection.planners import PlannedTrajectory, check_position_extrema, plan_trajectory
from stdm_drake.paths import TRAJECTORIES_DIR

NUM_STEPS = 100
DT = 0.01
SPEC_FILES = {"quintic": "tracking.yaml", "ruckig": "tracking_ruckig.yaml", "toppra": "tracking_toppra.yaml"}


@pytest.fixture(scope="module")
def kinematics():
    return RobotKinematics(robot=UR10)


@pytest.fixture(scope="module")
def spec():
    return load_tracking_spec(TRAJECTORIES_DIR / "tracking.yaml", robot=UR10)


@pytest.fixture(scope="module")
def start(kinematics, spec):
    sampling, planner = spec.sampling, spec.planner
    return initial_configuration(kinematics, sampling.initial_poses[0], planner)


@pytest.fixture(scope="module")
def goal(kinematics, start):
    """A goal near the first initial pose: 0.14 m away, rotated 0.28 rad about an oblique axis."""
    X0 = kinematics.tool_pose(start)
    axis = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    R = rotation_exp(0.28 * axis) @ X0.rotation().matrix()
    return RigidTransform(RotationMatrix(R), X0.translation() + np.array([0.10, -0.08, 0.06]))


def planner_config(spec, kind: str) -> PlannerConfig:
    """The spec's planner limits under planner `kind` (the spec files of the three kinds share them)."""
    return spec.planner.as_kind(kind)


def pose_errors(X_a: RigidTransform, X_b: RigidTransform) -> tuple[float, float]:
    """(position error m, rotation error rad) between two poses."""
    rotation = rotation_log(X_a.rotation().matrix() @ X_b.rotation().matrix().T)
    return float(np.linalg.norm(X_a.translation() - X_b.translation())), float(np.linalg.norm(rotation))


def assert_rest_to_rest(plan: PlannedTrajectory, q0: np.ndarray, *, accelerations_at_ends: bool = True):
    assert plan.t.shape == (NUM_STEPS + 1,) and plan.q.shape == plan.qd.shape == plan.qdd.shape == (NUM_STEPS + 1, 6)
    np.testing.assert_allclose(plan.t, np.arange(NUM_STEPS + 1) * DT, atol=1e-12)
    np.testing.assert_array_equal(plan.q[0], q0)
    np.testing.assert_array_equal(plan.q[-1], plan.q_goal)
    np.testing.assert_allclose(plan.qd[0], 0.0, atol=1e-12)
    np.testing.assert_allclose(plan.qd[-1], 0.0, atol=1e-12)
    np.testing.assert_allclose(plan.qdd[-1], 0.0, atol=1e-12)
    if accelerations_at_ends:
        np.testing.assert_allclose(plan.qdd[0], 0.0, atol=1e-12)
    assert 0.0 < plan.duration <= NUM_STEPS * DT + 1e-12


def assert_within_limits(plan: PlannedTrajectory, kinematics: RobotKinematics, config: PlannerConfig,
                         relative_tolerance: float = 1e-9):
    limits = kinematics.limits
    assert np.all(plan.q >= limits.position_lower) and np.all(plan.q <= limits.position_upper)
    slack = 1.0 + relative_tolerance
    assert np.all(np.abs(plan.qd) <= config.velocity_scale * limits.velocity * slack)
    assert np.all(np.abs(plan.qdd) <= np.asarray(config.acceleration_limits) * slack)


# ---------------------------------------------------------------------------------------------
# Kinematics
# ---------------------------------------------------------------------------------------------

def test_rotation_log_inverts_exp():
    rng = np.random.default_rng(3)
    for angle in (0.0, 1e-9, 0.3, 2.0, np.pi - 1e-3):
        axis = rng.standard_normal(3)
        w = angle * axis / np.linalg.norm(axis)
        np.testing.assert_allclose(rotation_log(rotation_exp(w)), w, atol=1e-9)


def test_ik_round_trip_from_nearby_seed(kinematics, start):
    rng = np.random.default_rng(7)
    for _ in range(5):
        q = start + rng.uniform(-0.3, 0.3, size=6)
        X = kinematics.tool_pose(q)
        q_ik = kinematics.inverse_kinematics(X, q + rng.uniform(-0.05, 0.05, size=6))
        position_error, rotation_error = pose_errors(kinematics.tool_pose(q_ik), X)
        assert position_error < 1e-9 and rotation_error < 1e-9
        np.testing.assert_allclose(q_ik, q, atol=1e-8)  # same branch as the seed


def test_global_ik_reaches_initial_pose_from_rough_seed(kinematics, spec):
    pose = spec.sampling.initial_poses[3]
    q = kinematics.inverse_kinematics_global(pose.pose(), np.asarray(pose.q_seed) + 0.3)
    position_error, rotation_error = pose_errors(kinematics.tool_pose(q), pose.pose())
    assert position_error < 1e-9 and rotation_error < 1e-9


def test_jacobian_and_bias_acceleration_match_finite_differences(kinematics, start):
    rng = np.random.default_rng(11)
    v = rng.uniform(-1.0, 1.0, size=6)
    h = 1e-6
    J = kinematics.jacobian(start)
    X = kinematics.tool_pose(start)
    X_h = kinematics.tool_pose(start + h * v)
    twist = np.concatenate([rotation_log(X_h.rotation().matrix() @ X.rotation().matrix().T),
                            X_h.translation() - X.translation()]) / h
    np.testing.assert_allclose(J @ v, twist, atol=1e-5)
    J_dot_v = (kinematics.jacobian(start + h * v) - kinematics.jacobian(start - h * v)) @ v / (2 * h)
    np.testing.assert_allclose(kinematics.bias_acceleration(start, v), J_dot_v, atol=1e-6)


def test_unreachable_goal_is_a_clear_planning_error(kinematics, spec, start):
    X_far = RigidTransform(kinematics.tool_pose(start).rotation(), [3.0, 0.0, 0.5])
    for kind in PLANNER_KINDS:
        with pytest.raises(PlanningError, match=r"out of reach: 3\.0\d\d m from the shoulder") as info:
            plan_trajectory(kinematics, start, X_far, config=planner_config(spec, kind))
        message = str(info.value)
        assert "\n" not in message and f"{kind} plan to goal pose xyz=(3.000, 0.000, 0.500)" in message
    with pytest.raises(PlanningError, match="inverse kinematics failed for pose"):
        kinematics.inverse_kinematics(X_far, start)


# ---------------------------------------------------------------------------------------------
# Quintic
# ---------------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def quintic_plan(kinematics, spec, start, goal):
    return plan_trajectory(kinematics, start, goal, config=planner_config(spec, "quintic"),
                           num_steps=NUM_STEPS, sample_period=DT)


def test_quintic_boundary_conditions_and_goal_pose(quintic_plan, kinematics, start, goal):
    assert quintic_plan.planner == "quintic"
    assert_rest_to_rest(quintic_plan, start)
    assert quintic_plan.duration == pytest.approx(NUM_STEPS * DT)
    position_error, rotation_error = pose_errors(kinematics.tool_pose(quintic_plan.q[-1]), goal)
    assert position_error < 1e-8 and rotation_error < 1e-8


def test_quintic_follows_line_and_geodesic(quintic_plan, kinematics, goal):
    X0 = quintic_plan.X_start
    dp = goal.translation() - X0.translation()
    w = rotation_log(goal.rotation().matrix() @ X0.rotation().matrix().T)
    for k in range(0, NUM_STEPS + 1, 5):
        tau = quintic_plan.t[k] / quintic_plan.duration
        s = 10 * tau**3 - 15 * tau**4 + 6 * tau**5
        X = kinematics.tool_pose(quintic_plan.q[k])
        np.testing.assert_allclose(X.translation(), X0.translation() + s * dp, atol=1e-9)
        R_expected = rotation_exp(s * w) @ X0.rotation().matrix()
        assert np.linalg.norm(rotation_log(X.rotation().matrix() @ R_expected.T)) < 1e-9


def test_quintic_derivatives_match_finite_differences(quintic_plan):
    plan = quintic_plan
    # Sampled central differences (O(dt^2) truncation error).
    np.testing.assert_allclose((plan.q[2:] - plan.q[:-2]) / (2 * DT), plan.qd[1:-1], atol=2e-3)
    np.testing.assert_allclose((plan.qd[2:] - plan.qd[:-2]) / (2 * DT), plan.qdd[1:-1], atol=2e-2)
    # Exact evaluation between samples, with a small step.
    h = 1e-4
    for time_s in (0.123, 0.5, 0.871):
        q, qd, qdd = plan.evaluate(time_s)
        q_plus, qd_plus, _ = plan.evaluate(time_s + h)
        q_minus, qd_minus, _ = plan.evaluate(time_s - h)
        np.testing.assert_allclose((q_plus - q_minus) / (2 * h), qd, atol=1e-5)
        np.testing.assert_allclose((qd_plus - qd_minus) / (2 * h), qdd, atol=1e-5)
    for k in (0, 37, NUM_STEPS):
        q, qd, qdd = plan.evaluate(plan.t[k])
        np.testing.assert_allclose(q, plan.q[k], atol=1e-9)
        np.testing.assert_allclose(qd, plan.qd[k], atol=1e-9)
        np.testing.assert_allclose(qdd, plan.qdd[k], atol=1e-9)


def test_quintic_respects_limits(quintic_plan, kinematics, spec):
    assert_within_limits(quintic_plan, kinematics, planner_config(spec, "quintic"))


def test_quintic_short_duration_holds_at_goal(kinematics, spec, start, goal):
    config = dataclasses.replace(planner_config(spec, "quintic"), duration_fraction=0.8)
    plan = plan_trajectory(kinematics, start, goal, config=config)
    assert plan.duration == pytest.approx(0.8)
    held = plan.t >= 0.8 - 1e-12
    np.testing.assert_array_equal(plan.q[held], np.tile(plan.q_goal, (held.sum(), 1)))
    assert np.all(plan.qd[held] == 0.0) and np.all(plan.qdd[held] == 0.0)
    assert_within_limits(plan, kinematics, config)


def test_quintic_limit_violations_are_planning_errors(kinematics, spec, start, goal):
    config = planner_config(spec, "quintic")
    with pytest.raises(PlanningError, match=r"needs at least 0\.\d+ s under the task-space limits, longer than "
                                            r"the 0\.100 s horizon"):
        plan_trajectory(kinematics, start, goal, config=config, num_steps=10, sample_period=DT)
    fast = dataclasses.replace(config, max_linear_speed=100.0, max_linear_acceleration=100.0,
                               max_angular_speed=100.0, max_angular_acceleration=100.0)
    with pytest.raises(PlanningError, match=r"_joint acceleration -?\d.* rad/s\^2 exceeds its limit .* by .* at t="):
        plan_trajectory(kinematics, start, goal, config=fast, num_steps=30, sample_period=DT)


# ---------------------------------------------------------------------------------------------
# ruckig
# ---------------------------------------------------------------------------------------------

@pytest.mark.parametrize("duration_fraction", [0.0, 1.0])
def test_ruckig_boundary_conditions_and_limits(kinematics, spec, start, goal, quintic_plan, duration_fraction):
    config = dataclasses.replace(planner_config(spec, "ruckig"), duration_fraction=duration_fraction)
    plan = plan_trajectory(kinematics, start, goal, config=config, num_steps=NUM_STEPS, sample_period=DT)
    assert plan.planner == "ruckig"
    assert_rest_to_rest(plan, start)
    if duration_fraction == 0.0:
        assert plan.duration < 0.9 * NUM_STEPS * DT  # time-optimal: finishes early and holds
    else:
        assert plan.duration == pytest.approx(NUM_STEPS * DT)
    np.testing.assert_allclose(plan.q_goal, quintic_plan.q_goal, atol=1e-9)  # same IK branch
    position_error, rotation_error = pose_errors(kinematics.tool_pose(plan.q[-1]), goal)
    assert position_error < 1e-8 and rotation_error < 1e-8
    assert_within_limits(plan, kinematics, config)
    jerk = np.diff(plan.qdd, axis=0) / DT  # mean jerk over each sample interval
    assert np.all(np.abs(jerk) <= np.asarray(config.jerk_limits) * (1 + 1e-9))
    # No overshoot: each joint stays between its start and goal positions.
    low, high = np.minimum(start, plan.q_goal), np.maximum(start, plan.q_goal)
    assert np.all(plan.q >= low - 1e-9) and np.all(plan.q <= high + 1e-9)
    h = 1e-5
    for time_s in (0.05, plan.duration / 2):
        _, qd, qdd = plan.evaluate(time_s)
        q_plus, qd_plus, _ = plan.evaluate(time_s + h)
        q_minus, qd_minus, _ = plan.evaluate(time_s - h)
        np.testing.assert_allclose((q_plus - q_minus) / (2 * h), qd, atol=1e-6)
        np.testing.assert_allclose((qd_plus - qd_minus) / (2 * h), qdd, atol=1e-4)


def test_ruckig_position_extrema_checked_against_joint_limits(kinematics, start, quintic_plan):
    generator = ruckig.Ruckig(6)
    inp = ruckig.InputParameter(6)
    inp.current_position = start.tolist()
    inp.target_position = quintic_plan.q_goal.tolist()
    inp.max_velocity, inp.max_acceleration, inp.max_jerk = [1.0] * 6, [4.0] * 6, [40.0] * 6
    trajectory = ruckig.Trajectory(6)
    generator.calculate(inp, trajectory)
    limits = kinematics.limits
    check_position_extrema(trajectory.position_extrema, limits.position_lower, limits.position_upper, "ok")
    j = int(np.argmax(np.abs(quintic_plan.q_goal - start)))
    upper = limits.position_upper.copy()
    upper[j] = max(start[j], quintic_plan.q_goal[j]) - 0.01
    lower = limits.position_lower.copy()
    lower[j] = min(start[j], quintic_plan.q_goal[j]) - 1.0
    with pytest.raises(PlanningError, match=r"ruckig test: \w+_joint reaches .* outside its position limit .* by "
                                            r"0\.0100 rad"):
        check_position_extrema(trajectory.position_extrema, lower, upper, "ruckig test", kinematics.joint_names)


def test_ruckig_too_short_horizon_is_a_planning_error(kinematics, spec, start, goal):
    with pytest.raises(PlanningError, match=r"jerk-limited motion needs 0\.\d+ s, longer than the 0\.150 s horizon"):
        plan_trajectory(kinematics, start, goal, config=planner_config(spec, "ruckig"), num_steps=15,
                        sample_period=DT)


# ---------------------------------------------------------------------------------------------
# toppra
# ---------------------------------------------------------------------------------------------

def test_toppra_boundary_conditions_limits_and_goal(kinematics, spec, start, goal, quintic_plan):
    config = planner_config(spec, "toppra")
    plan = plan_trajectory(kinematics, start, goal, config=config, num_steps=NUM_STEPS, sample_period=DT)
    assert plan.planner == "toppra"
    # Time-optimal: the acceleration jumps at the start, so only q and qd are at rest there.
    assert_rest_to_rest(plan, start, accelerations_at_ends=False)
    assert plan.duration < 0.9 * NUM_STEPS * DT
    np.testing.assert_allclose(plan.q_goal, quintic_plan.q_goal, atol=1e-9)
    position_error, rotation_error = pose_errors(kinematics.tool_pose(plan.q[-1]), goal)
    assert position_error < 1e-8 and rotation_error < 1e-8
    assert_within_limits(plan, kinematics, config, relative_tolerance=1e-6)
    # Some joint runs at (nearly) a velocity or acceleration limit: the re-timing is time-optimal.
    velocity_use = np.abs(plan.qd) / (config.velocity_scale * kinematics.limits.velocity)
    acceleration_use = np.abs(plan.qdd) / np.asarray(config.acceleration_limits)
    assert max(velocity_use.max(), acceleration_use.max()) > 0.95
    # The motion comes to rest continuously at the end of the re-timed motion.
    np.testing.assert_allclose(plan.evaluate(plan.duration - 1e-9)[1], 0.0, atol=1e-6)
    # The joint path is the IK'd task-space line (up to the spline interpolation error).
    X0 = plan.X_start
    dp = goal.translation() - X0.translation()
    for q in plan.q[::4]:
        offset = kinematics.tool_pose(q).translation() - X0.translation()
        assert np.linalg.norm(offset - (offset @ dp) / (dp @ dp) * dp) < 1e-4


def test_toppra_too_short_horizon_is_a_planning_error(kinematics, spec, start, goal):
    with pytest.raises(PlanningError, match=r"time-optimal motion needs 0\.\d+ s, longer than the 0\.100 s horizon"):
        plan_trajectory(kinematics, start, goal, config=planner_config(spec, "toppra"), num_steps=10,
                        sample_period=DT)


# ---------------------------------------------------------------------------------------------
# Sampling the protocol
# ---------------------------------------------------------------------------------------------

def small_sampling(spec, **changes) -> TaskSpaceSamplingConfig:
    return dataclasses.replace(spec.sampling, initial_poses=spec.sampling.initial_poses[:2], num_final_per_initial=3, **changes)


@pytest.mark.slow
def test_sample_task_plans_resamples_rejected_and_is_deterministic(kinematics, spec):
    sampling, planner = small_sampling(spec), spec.planner  # both initial poses are at z = 0.45 m
    z_max = 0.48

    def is_collision_free(q):  # stands in for a SceneGraph check: rejects tool heights above z_max
        return kinematics.tool_pose(q).translation()[2] <= z_max

    def run(seed, messages):
        return sample_task_plans(kinematics, sampling, planner, DT, np.random.default_rng(seed),
                                 is_collision_free=is_collision_free, on_reject=messages.append)

    rejected = []
    first = run(5, rejected)
    assert [index for index, _ in first] == [0, 0, 0, 1, 1, 1]
    assert rejected and all("rejected, resampled" in message and "self-collision at t=" in message
                            for message in rejected)
    for _, plan in first:
        assert all(is_collision_free(q) for q in plan.q)
    unreachable, lines = dataclasses.replace(sampling, max_resample_attempts=3, position_offset=[50.0] * 3), []
    with pytest.raises(PlanningError, match="after 4 attempts"):   # every goal out of reach: no line before the refusal
        sample_task_plans(kinematics, unreachable, planner, DT, np.random.default_rng(5), on_reject=lines.append)
    assert lines == []
    again = run(5, [])
    for (index_a, a), (index_b, b) in zip(first, again):
        assert index_a == index_b
        np.testing.assert_array_equal(a.X_goal.GetAsMatrix4(), b.X_goal.GetAsMatrix4())
        np.testing.assert_array_equal(a.q, b.q)
        np.testing.assert_array_equal(a.qdd, b.qdd)
    other = run(6, [])
    assert not np.array_equal(first[0][1].q, other[0][1].q)


def test_sample_task_plans_gives_up_naming_the_initial_pose(kinematics, spec, start):
    sampling = small_sampling(spec, max_resample_attempts=2)
    messages = []
    with pytest.raises(PlanningError, match=r"initial pose 0 \(xyz=\(0\.650, 0\.350, 0\.450\) m .*\): no feasible "
                                            r"final pose for plan 0 after 3 attempts; last: .*self-collision"):
        sample_task_plans(kinematics, sampling, spec.planner, DT, np.random.default_rng(0),
                          is_collision_free=lambda q: np.allclose(q, start, atol=1e-12), on_reject=messages.append)
    assert messages == []   # (the refusal alone: no rejection line before it)


@pytest.mark.slow
def test_sample_task_plans_rejects_limit_violations(kinematics, spec):
    # Tight acceleration limits reject some final poses; the kept ones all respect them.
    planner = dataclasses.replace(spec.planner, acceleration_limits=[1.2] * 6)
    sampling = small_sampling(spec, max_resample_attempts=50)
    messages = []
    plans = sample_task_plans(kinematics, sampling, planner, DT, np.random.default_rng(2), on_reject=messages.append)
    assert len(plans) == 6 and messages
    assert all("acceleration" in message and "exceeds its limit" in message for message in messages)
    for _, plan in plans:
        assert_within_limits(plan, kinematics, planner)


def test_unreachable_initial_pose_is_named(kinematics, spec):
    far = InitialPose(xyz=[2.5, 0.0, 0.4], rpy=[np.pi, 0.0, 0.0], q_seed=spec.sampling.initial_poses[0].q_seed)
    sampling = dataclasses.replace(spec.sampling, initial_poses=[spec.sampling.initial_poses[0], far], num_final_per_initial=1)
    with pytest.raises(PlanningError, match=r"initial pose 1 \(xyz=\(2\.500, 0\.000, 0\.400\) .*\) is unreachable"):
        sample_task_plans(kinematics, sampling, spec.planner, DT, np.random.default_rng(0))


@pytest.mark.slow
@pytest.mark.parametrize("kind", PLANNER_KINDS)
def test_default_spec_yields_100_valid_plans(kinematics, kind):
    loaded = load_tracking_spec(TRAJECTORIES_DIR / SPEC_FILES[kind], robot=UR10)
    sampling, planner = loaded.sampling, loaded.planner
    assert planner.kind == kind
    messages = []
    started = time.perf_counter()
    plans = sample_task_plans(kinematics, sampling, planner, DT, np.random.default_rng(0), on_reject=messages.append)
    elapsed = time.perf_counter() - started
    print(f"{kind}: 100 plans in {elapsed:.2f} s")
    assert messages == []  # the default spec needs no resampling
    assert len(plans) == 100
    assert [index for index, _ in plans] == [i for i in range(4) for _ in range(25)]
    for index, plan in plans:
        q0 = initial_configuration(kinematics, sampling.initial_poses[index], planner)
        np.testing.assert_allclose(plan.q[0], q0, atol=1e-9)
        assert_rest_to_rest(plan, plan.q[0], accelerations_at_ends=kind != "toppra")
        assert_within_limits(plan, kinematics, planner, relative_tolerance=1e-6)
        position_error, rotation_error = pose_errors(kinematics.tool_pose(plan.q[-1]), plan.X_goal)
        assert position_error < 1e-8 and rotation_error < 1e-8
        offset = plan.X_goal.translation() - plan.X_start.translation()
        assert np.all(np.abs(offset) <= np.asarray(sampling.position_offset) + 1e-12)
        angle = np.linalg.norm(rotation_log(plan.X_goal.rotation().matrix() @ plan.X_start.rotation().matrix().T))
        assert angle <= sampling.orientation_max_angle + 1e-9


# ---------------------------------------------------------------------------------------------
# Tracking spec YAML
# ---------------------------------------------------------------------------------------------

def test_spec_variants_share_the_sampling_protocol():
    specs = {kind: load_tracking_spec(TRAJECTORIES_DIR / name, robot=UR10) for kind, name in SPEC_FILES.items()}
    reference_sampling, reference_planner = specs["quintic"].sampling, specs["quintic"].planner
    assert len(reference_sampling.initial_poses) == 4 and reference_sampling.num_final_per_initial == 25
    assert reference_sampling.num_steps == 100
    for kind, spec in specs.items():
        sampling, planner = spec.sampling, spec.planner
        assert planner.kind == kind
        assert sampling == reference_sampling
        assert planner.as_kind("quintic") == reference_planner       # the same shared limits


def test_planners_are_tagged_and_the_old_kind_layout_loads_with_a_warning(tmp_path, capsys):
    """`planner: !Ruckig {...}` picks the type by its tag; a planner in the layout before the tags (`kind:`
    among the fields, the other kinds' fields too) loads to the same config with one warning line."""
    text = (TRAJECTORIES_DIR / "tracking.yaml").read_text()
    sampling = text[:text.index("\n  planner:") + 1]       # `protocol: !Tracking` and its sampling section
    new = tmp_path / "new.yaml"
    new.write_text(sampling + "  planner: !Ruckig\n    jerk_limits: [20.0]\n    velocity_scale: 0.4\n")
    old_sampling = "\n".join(line[2:] for line in sampling.splitlines() if line.startswith("  "))
    old = tmp_path / "old.yaml"   # the layout before the tags: sampling and planner at the top, planner `kind:`
    old.write_text(old_sampling + "\nplanner:\n  kind: ruckig\n  jerk_limits: [20.0]\n  velocity_scale: 0.4\n"
                   "  toppra_gridpoints: 99\n  max_linear_speed: 0.5\n")
    loaded = load_tracking_spec(new, robot=UR10).planner
    assert isinstance(loaded, Ruckig) and loaded.jerk_limits == [20.0] * 6 and loaded.velocity_scale == 0.4
    assert capsys.readouterr().err == ""
    assert load_tracking_spec(old, robot=UR10).planner == loaded
    warnings = capsys.readouterr().err.strip().splitlines()
    assert len(warnings) == 2 and "old `kind: ruckig` layout" in warnings[0] and "planner: !Ruckig" in warnings[0]
    assert "write `protocol: !Tracking`" in warnings[1]
    assert loaded.record()["kind"] == "ruckig" and "toppra_gridpoints" not in loaded.record()


@pytest.mark.parametrize("text, message", [
    ("planner:\n  kind: spline\n", r"planner: kind must be one of quintic, ruckig, toppra, got 'spline'"),
    ("planner: !Spline\n  velocity_scale: 0.5\n", r"did not match any of the allowed type options"),
    ("planner: !Quintic\n  jerk_limits: [1.0]\n", r"The fields \['jerk_limits'\] were unknown"),
    ("planner:\n  knd: quintic\n", r"planner: unknown fields \['knd'\]"),
    ("planner:\n  velocity_scale: fast\n", r"planner: could not convert string to float"),
    ("sampling:\n  num_steps: 1.5\n", r"sampling.num_steps is written 1.5, not a whole number, where a whole number goes"),
    ("planner: {kind: quintic\n", r"malformed tracking spec: while parsing a flow mapping"),
    ("- 1\n- 2\n", r"malformed tracking spec: YAML root was a <class 'list'>"),
    ("", r"malformed tracking spec"),
    ("sampling:\n  initial_poses:\n    - xyz: [1, 2]\n", r"sampling: initial_poses\[0\]\.xyz must be 3 numbers within \+-1000 m"),
    ("planner:\n  acceleration_limits: [1, 2]\n", r"planner: planner acceleration_limits has 2 values; the robot has 6 joints"),
])
def test_malformed_spec_is_an_input_error_naming_the_file(tmp_path, text, message):
    path = tmp_path / "bad_spec.yaml"
    path.write_text(text)
    with pytest.raises(InputError, match=message) as info:
        load_tracking_spec(path, robot=UR10)
    assert str(info.value).startswith(f"{path}: ") and "\n" not in str(info.value)


def test_missing_spec_file_is_an_input_error(tmp_path):
    with pytest.raises(InputError, match="tracking spec not found: .*missing.yaml"):
        load_tracking_spec(tmp_path / "missing.yaml", robot=UR10)


def test_invalid_planner_config_in_code_is_an_input_error(kinematics, start, goal):
    with pytest.raises(InputError, match="velocity_scale must be in"):
        plan_trajectory(kinematics, start, goal, config=Quintic(velocity_scale=1.5))


def test_near_singular_jacobian_is_a_planning_error(kinematics, spec, start, goal):
    # The default poses stay well conditioned (condition number < 10); a strict bound trips the guard.
    for kind in ("quintic", "toppra"):
        config = dataclasses.replace(planner_config(spec, kind), max_jacobian_condition=2.0)
        with pytest.raises(PlanningError, match=r"near a singularity .*: Jacobian condition number \d+\.?\d* > 2"):
            plan_trajectory(kinematics, start, goal, config=config)
    wrist_aligned = start.copy()
    wrist_aligned[4] = 0.0  # wrist_2 = 0: wrist_1 and wrist_3 axes parallel
    assert np.linalg.cond(kinematics.jacobian(wrist_aligned)) > 1e6
    with pytest.raises(PlanningError, match="quintic plan .*: near a singularity at the start"):
        plan_trajectory(kinematics, wrist_aligned, goal, config=planner_config(spec, "quintic"))
