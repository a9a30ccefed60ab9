"""A switch of expert continues from where the end effector is: no step larger than the demonstrations' largest."""

from dataclasses import replace

import numpy as np
import pytest

from cnep.runtime import STATE_KEY, Columns, ConditioningPolicy, Policy, PolicyError, PolicySpec
from tests.runtime.fakes import TIME_BASE

WIDTH = 8  # x y z qx qy qz qw gripper: a motion model
STEP = {"x": 0.05, "y": 0.02, "z": 0.02, "qx": 0.1, "qy": 0.1, "qz": 0.1, "qw": 0.1}  # the demonstrations' largest
PATHS = np.array([[0.0, 0.0, 0.3], [1.0, -0.5, 0.3]])  # (2, 3): where each expert's path holds the end effector


class TwoPaths:
    """Expert e's path holds x y z at PATHS[e] and the orientation at rest; the gate picks expert `gates[k]` at the
    k-th step (the last one after the script)."""

    def __init__(self, gates: list[int]) -> None:
        self.gates, self.k = gates, 0

    def encode(self, obs: np.ndarray) -> np.ndarray:
        return np.zeros((len(obs), 2), dtype=np.float32)

    def decode(self, r: np.ndarray, query: np.ndarray):
        m = len(query)
        mean = np.zeros((2, m, WIDTH), dtype=np.float32)
        mean[:, :, :3] = PATHS[:, None, :]
        mean[:, :, 6] = 1.0  # qw
        gate = np.eye(2, dtype=np.float32)[self.gates[min(self.k, len(self.gates) - 1)]]
        self.k += 1
        return gate, mean, np.full_like(mean, 0.01)


def motion_spec(max_step: dict | None = STEP) -> PolicySpec:
    everything = ((0, WIDTH),)
    columns = Columns(everything, (), everything, np.zeros(WIDTH), np.ones(WIDTH))
    return PolicySpec(columns, 2, None, (((0, WIDTH), (0, WIDTH)),), TIME_BASE, max_step=max_step)


def follow(policy: Policy, steps: int) -> list:
    """The episode of a robot that reaches each step's first waypoint: its states and each step's result."""
    state = np.r_[PATHS[0], 0, 0, 0, 1, 0.0]
    results = []
    for _ in range(steps):
        result = policy.step({STATE_KEY: state})
        results.append((state.copy(), result))
        state = np.r_[result.waypoints[0, :7], state[7]]
    return results


def test_after_a_switch_every_waypoint_moves_at_most_the_largest_step_until_the_new_path_is_reached():
    policy = Policy(
        TwoPaths([0] * 5 + [1]), motion_spec(), waypoints=4, conditioning=ConditioningPolicy(switch_margin=0)
    )
    results = follow(policy, 40)
    assert [k for k, (_, r) in enumerate(results) if r.switch is not None] == [5]
    bound = np.array([STEP[name] for name in ("x", "y", "z")])
    for state, result in results:
        path = np.vstack([state[:3], result.waypoints[:, :3]])  # (1 + W, 3): from where the end effector is
        assert (np.abs(np.diff(path, axis=0)) <= bound + 1e-6).all()
    reached = next(k for k, (state, _) in enumerate(results) if np.allclose(state[:3], PATHS[1], atol=1e-6))
    assert reached == 5 + int(np.ceil((np.abs(PATHS[1] - PATHS[0]) / bound).max()))  # the slowest axis: y, 25 steps
    for _, result in results[reached:]:  # on the new path: its own waypoints again
        np.testing.assert_allclose(result.waypoints[:, :3], np.broadcast_to(PATHS[1], (4, 3)), atol=1e-6)


def test_without_the_demonstrations_largest_step_a_switch_jumps_to_the_new_path():
    """A policy whose spec has no bound (a checkpoint written before it was stored) hands out the new path as is."""
    policy = Policy(TwoPaths([0, 1]), motion_spec(max_step=None), conditioning=ConditioningPolicy(switch_margin=0))
    (_, first), (state, switched) = follow(policy, 2)
    assert switched.switch is not None
    np.testing.assert_allclose(switched.waypoints[0, :3] - state[:3], PATHS[1] - PATHS[0], atol=1e-6)


def test_a_first_step_is_not_bound_nor_a_pose_entry_that_never_moved():
    spec = motion_spec(max_step={**STEP, "x": 0.0})  # x never moved in the demonstrations: no bound on it
    policy = Policy(TwoPaths([0, 0, 1]), spec, conditioning=ConditioningPolicy(switch_margin=0))
    (_, first), _, (state, switched) = follow(policy, 3)
    assert switched.switch is not None
    assert switched.waypoints[0, 0] == pytest.approx(PATHS[1, 0])  # x: unbound
    assert switched.waypoints[0, 1] - state[1] == pytest.approx(-STEP["y"])  # y: the largest step towards the path
    policy.reset()
    again = policy.step({STATE_KEY: np.r_[PATHS[0], 0, 0, 0, 1, 0.0]})  # expert 1 from the start: its own path
    assert again.switch is None and np.allclose(again.waypoints[0, :3], PATHS[1], atol=1e-6)


def test_the_spec_carries_the_largest_steps_and_refuses_what_they_cannot_be():
    spec = motion_spec()
    assert PolicySpec.from_dict(spec.to_dict()).max_step == STEP
    older = {k: v for k, v in spec.to_dict().items() if k != "max_step"}
    assert PolicySpec.from_dict(older).max_step is None
    for wrong in ({"gripper": 0.1}, {"x": -1.0}, {"x": float("inf")}, {"x": "far"}):
        with pytest.raises(PolicyError, match="max_step"):
            replace(spec, max_step=wrong)
