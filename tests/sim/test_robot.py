"""A robot's constraints on the floating gripper: the target follower within the arm's limits, the demonstrators'
moves planned inside them, the sensing noise and the plan a scripted demonstrator hands out and replans."""

import importlib.util
import math

import numpy as np
import pytest

import cnep.sim  # first: it chooses MuJoCo's headless renderer before MuJoCo loads

if not all(importlib.util.find_spec(name) for name in cnep.sim.EXTRA):
    pytest.skip("the sim extra is not installed", allow_module_level=True)

from cnep.sim import scene as S  # noqa: E402
from cnep.sim.controller import PLAN_SHARE, Follower, min_jerk_steps, rotation  # noqa: E402
from cnep.sim.noise import noisy_frame, noisy_pose  # noqa: E402
from cnep.sim.paths import Plan, minimum_jerk  # noqa: E402
from cnep.sim.robot import ARM, TELEPORT, RobotSettings  # noqa: E402

DT, STEPS = S.TIMESTEP_S, round(S.CONTROL_PERIOD_S / S.TIMESTEP_S)  # physics steps of a control period
HOME = np.array([1.0, 0.0, 0.0, 0.0])  # wxyz


def _follow(follower: Follower, waypoints: list[tuple[np.ndarray, np.ndarray]]) -> dict[str, np.ndarray]:
    """Each waypoint (position, quaternion wxyz) aimed at for a control period: the target's positions, velocities,
    angular velocities and quaternions at every physics step."""
    trace = {"position": [], "velocity": [], "angular": [], "quat": []}
    for position, quat in waypoints:
        follower.aim(position, quat)
        for _ in range(STEPS):
            follower.step()
            for key in trace:
                trace[key].append(getattr(follower, key).copy())
    return {key: np.asarray(values) for key, values in trace.items()}


def test_a_jump_is_crossed_within_the_arms_speed_and_acceleration_and_reached_without_overshoot():
    follower = Follower(ARM, DT, S.CONTROL_PERIOD_S)
    follower.reset(np.zeros(3), HOME)
    quarter = np.array([math.cos(math.pi / 4), 0.0, 0.0, math.sin(math.pi / 4)])  # 90 degrees about z
    trace = _follow(follower, [(np.array([0.3, 0.0, 0.0]), quarter)] * 15)  # 1.5 s at the same waypoint
    speed = np.linalg.norm(trace["velocity"], axis=1)
    acceleration = np.linalg.norm(np.diff(trace["velocity"], axis=0), axis=1) / DT
    angular = np.linalg.norm(trace["angular"], axis=1)
    assert speed.max() <= ARM.max_speed + 1e-9 and speed.max() > 0.9 * ARM.max_speed  # it went as fast as allowed
    assert acceleration.max() <= ARM.max_acceleration + 1e-6
    assert angular.max() <= ARM.max_angular_speed + 1e-9
    assert np.linalg.norm(np.diff(trace["angular"], axis=0), axis=1).max() / DT <= ARM.max_angular_acceleration + 1e-6
    assert trace["position"][:, 0].max() < 0.3 + 0.002  # braked before the waypoint
    assert trace["position"][STEPS * 3, 0] < 0.2  # the teleporting target would be there at once
    np.testing.assert_allclose(trace["position"][-1], [0.3, 0.0, 0.0], atol=1e-6)
    assert np.linalg.norm(rotation(quarter, trace["quat"][-1])) < 1e-4  # rad: turned there too


def test_a_minimum_jerk_move_planned_within_the_limits_is_tracked_without_lag():
    distance = 0.3
    steps = min_jerk_steps(distance, 0.0, ARM, S.CONTROL_PERIOD_S)
    waypoints = distance * minimum_jerk(steps)
    peak_speed = np.abs(np.diff(np.r_[0.0, waypoints])).max() / S.CONTROL_PERIOD_S
    assert peak_speed <= PLAN_SHARE * ARM.max_speed  # planned inside the limits
    assert min_jerk_steps(distance, 0.0, TELEPORT, S.CONTROL_PERIOD_S) == 1  # no limit, no minimum
    follower = Follower(ARM, DT, S.CONTROL_PERIOD_S)
    follower.reset(np.zeros(3), HOME)
    trace = _follow(follower, [(np.array([x, 0.0, 0.0]), HOME) for x in waypoints])
    reached = trace["position"][STEPS - 1 :: STEPS, 0]  # where the target is at the end of each control period
    assert np.abs(reached - waypoints).max() < 0.003
    assert np.abs(trace["angular"]).max() == 0  # nothing to turn: the orientation is left alone


def test_a_robot_without_a_speed_limit_has_no_follower_and_bad_limits_or_noise_are_refused():
    with pytest.raises(ValueError, match="speed limit"):
        Follower(TELEPORT, DT, S.CONTROL_PERIOD_S)
    with pytest.raises(ValueError, match="must be > 0"):
        RobotSettings(max_speed=0.5, max_acceleration=0.0)
    with pytest.raises(ValueError, match="light_jitter"):
        RobotSettings(light_jitter=1.0)
    assert ARM.randomised and not TELEPORT.randomised


def test_the_reported_pose_carries_the_trackers_noise_drawn_from_the_generator():
    rng = np.random.default_rng(0)
    state = np.array([0.1, -0.2, 0.15, 0.0, 0.0, 0.0, 1.0, 0.03])
    draws = np.stack([noisy_pose(state, rng, ARM) for _ in range(2000)])
    np.testing.assert_allclose(draws[:, :3].std(axis=0), ARM.pose_noise_m, rtol=0.1)
    angles = [np.linalg.norm(rotation(np.roll(q, 1), np.roll(state[3:7], 1))) for q in draws[:, 3:7]]
    per_axis = math.degrees(math.sqrt(np.mean(np.square(angles)) / 3))  # the error's spread on each axis
    assert abs(per_axis - ARM.pose_noise_deg) < 0.1
    np.testing.assert_allclose(np.linalg.norm(draws[:, 3:7], axis=1), 1.0, atol=1e-12)
    assert (draws[:, 7] == state[7]).all()  # the gripper's opening is measured exactly
    again = noisy_pose(state, np.random.default_rng(0), ARM)
    np.testing.assert_array_equal(again, draws[0])


def test_a_frames_sensor_noise_keeps_it_uint8_and_within_range():
    frame = np.full((12, 16, 3), 250, np.uint8)
    frame[0] = 2
    noisy = noisy_frame(frame, np.random.default_rng(0), ARM.pixel_noise)
    assert noisy.dtype == np.uint8 and noisy.shape == frame.shape and noisy.max() <= 255
    assert 1.5 < np.abs(noisy.astype(float) - frame).mean() < 4.0  # about sigma * 0.8 away on average


def test_a_plan_hands_out_its_waypoints_holds_the_last_and_replans_what_is_left():
    plan = Plan(np.arange(3 * 8, dtype=float).reshape(3, 8))
    assert plan.last() is None
    assert [plan.next()[0] for _ in range(4)] == [0.0, 8.0, 16.0, 16.0]  # the last one held
    plan.replan(np.full((2, 8), -1.0))
    assert plan.last()[0] == 16.0 and plan.next()[0] == -1.0 and plan.given == 5
