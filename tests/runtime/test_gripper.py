"""The gripper command: two values and a threshold with hysteresis from the demonstrations, applied by the Policy."""

import numpy as np
import pytest

from cnep.runtime import STATE_KEY, GripperCommand, Policy, PolicyError, PolicySpec
from cnep.runtime.gripper import HYSTERESIS
from tests.runtime.fakes import WIDTH, ScriptedNetwork, camera_spec, mean_colour_features
from tests.runtime.test_policy import observation


def demonstrations(rng: np.random.Generator) -> np.ndarray:
    """Openings (m) of 20 demonstrations: open at 0.08, closed at 0.01 for a while, ramps of 5 steps between."""
    episodes = []
    for _ in range(20):
        open_, closed = 0.08 + rng.normal(0, 1e-3, 30), 0.01 + rng.normal(0, 1e-3, 20)
        episodes.append(np.r_[open_[:15], np.linspace(0.08, 0.01, 5), closed, np.linspace(0.01, 0.08, 5), open_[15:]])
    return np.concatenate(episodes)


def test_the_two_values_are_the_demonstrations_open_and_closed_and_the_thresholds_lie_between():
    command = GripperCommand.from_demonstrations(demonstrations(np.random.default_rng(0)))
    assert command.low == pytest.approx(0.01, abs=5e-4) and command.high == pytest.approx(0.08, abs=5e-4)
    gap = command.high - command.low
    assert command.rise == pytest.approx(command.low + (0.5 + HYSTERESIS) * gap)
    assert command.fall == pytest.approx(command.low + (0.5 - HYSTERESIS) * gap)
    assert GripperCommand.from_dict(command.to_dict()) == command


def test_a_gripper_that_never_moves_has_one_value():
    command = GripperCommand.from_demonstrations(np.full(50, 0.04))
    assert command.low == command.high == 0.04
    assert {command.command(v, 0.04) for v in (-1.0, 0.04, 1.0)} == {0.04}


def test_the_command_holds_between_the_thresholds():
    command = GripperCommand.from_levels(0.0, 1.0)  # rise 0.75, fall 0.25
    predictions = [0.1, 0.6, 0.74, 0.76, 0.5, 0.3, 0.26, 0.24, 0.5, 0.8]
    commands, last = [], 0.0
    for value in predictions:
        last = command.command(value, last)
        commands.append(last)
    assert commands == [0.0, 0.0, 0.0, 1.0, 1.0, 1.0, 1.0, 0.0, 0.0, 1.0]
    assert command.nearest(0.3) == 0.0 and command.nearest(0.7) == 1.0


def test_bad_commands_are_refused():
    with pytest.raises(PolicyError, match="low <= fall <= rise <= high"):
        GripperCommand(0.0, 1.0, 0.2, 0.8)
    with pytest.raises(PolicyError, match="finite"):
        GripperCommand.from_demonstrations(np.array([0.0, np.nan]))
    with pytest.raises(PolicyError, match="low, high, rise and fall"):
        GripperCommand.from_dict({"low": 0})


def test_the_policy_puts_the_command_in_the_actions_gripper_and_keeps_the_prediction():
    spec = camera_spec()
    loc, scale = spec.columns.loc[WIDTH - 1], spec.columns.scale[WIDTH - 1]
    predicted = np.array([0.9, 0.7, 0.5, 0.2, 0.3, 0.6, 0.8, 0.6])  # the gripper, in the data's unit
    expected = [1.0, 1.0, 1.0, 0.0, 0.0, 0.0, 1.0, 1.0]  # starting from the observed state's gripper, 0.95
    gripper = GripperCommand.from_levels(0.0, 1.0)
    network = ScriptedNetwork([[1, 0, 0]], last=(predicted - loc) / scale)
    policy = Policy(
        network,
        PolicySpec(spec.columns, spec.n_experts, spec.features, spec.state, spec.time_base, gripper=gripper),
        mean_colour_features,
    )
    for k in range(len(predicted)):
        obs = observation(k)
        obs[STATE_KEY][7] = 0.95
        step = policy.step(obs)
        assert step.gripper == expected[k]
        assert step.waypoints[0, 3] == pytest.approx(predicted[k], abs=1e-5)  # the raw prediction stays
    policy.reset()
    network.decoded = 0  # the script again: 0.9, then 0.7
    for k, command in enumerate((1.0, 1.0)):
        obs = observation(k)
        obs[STATE_KEY][7] = 0.05  # a closed gripper: the prediction 0.9 opens it, 0.7 keeps it open
        action = policy.select_action(obs)
        assert action[3] == command and action.shape == (4,)
    overridden = Policy(ScriptedNetwork([[1, 0, 0]]), spec, mean_colour_features, gripper=gripper)
    assert overridden.step(observation(0)).gripper in (0.0, 1.0)
    assert Policy(ScriptedNetwork([[1, 0, 0]]), spec, mean_colour_features).step(observation(0)).gripper is None


def test_the_spec_carries_the_command_through_its_dict_and_reads_one_without_it():
    spec = camera_spec()
    with_gripper = PolicySpec(
        spec.columns,
        spec.n_experts,
        spec.features,
        spec.state,
        spec.time_base,
        gripper=GripperCommand.from_levels(0, 1),
    )
    assert PolicySpec.from_dict(with_gripper.to_dict()).gripper == with_gripper.gripper
    old = {key: value for key, value in spec.to_dict().items() if key != "gripper"}
    old["conditioning"] = {"window": 10, "anchors": 1}  # as a format 1 manifest has it
    assert PolicySpec.from_dict(old).gripper is None
