"""The gripper command: two values and a threshold with hysteresis from the demonstrations, applied by the Policy."""

from dataclasses import replace

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


def measured_openings(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """20 demonstrations whose gripper is the measured opening (m): open at 0.08, closed on an object it reads the
    object's width, 0.02 to 0.04 m, ramps of 5 steps between; their values and each one's first."""
    episodes = []
    for width in np.linspace(0.02, 0.04, 20):
        held = width + rng.normal(0, 5e-4, 20)
        episodes.append(np.r_[np.full(15, 0.08), np.linspace(0.08, width, 5), held, np.linspace(width, 0.08, 5)])
    return np.concatenate(episodes), np.array([e[0] for e in episodes])


def stepped(command: GripperCommand, predicted: list[float], observed: float) -> list:
    """The steps of a policy with `command` whose gripper prediction is `predicted[k]` at step k, the gripper reading
    `observed`."""
    spec = camera_spec()
    loc, scale = spec.columns.loc[WIDTH - 1], spec.columns.scale[WIDTH - 1]
    network = ScriptedNetwork([[1, 0, 0]], last=(np.array(predicted) - loc) / scale)
    policy = Policy(network, replace(spec, gripper=command), mean_colour_features)
    steps = []
    for k in range(len(predicted)):
        obs = observation(k)
        obs[STATE_KEY][7] = observed
        steps.append(policy.step(obs))
    return steps


def test_a_measured_opening_closed_on_an_object_says_closed_whatever_the_objects_width():
    values, starts = measured_openings(np.random.default_rng(0))
    command = GripperCommand.from_demonstrations(values, starts)
    assert command.closed == "low" and command.low == pytest.approx(0.03, abs=3e-3) and command.high == 0.08
    # open, then closing on objects of the training widths, a wider one (between the thresholds), a narrower one
    predicted = [0.08, 0.03, 0.02, 0.05, 0.01, 0.03, 0.08]
    steps = stepped(command, predicted, observed=0.08)
    assert [s.gripper_closed for s in steps] == [False, True, True, True, True, True, False]
    assert [s.gripper for s in steps] == [command.high] + [command.low] * 5 + [command.high]
    # an episode that starts holding an object: its reading, the object's width, is closed
    held = stepped(command, [0.05, 0.05], observed=0.045)
    assert [s.gripper_closed for s in held] == [True, True]


def test_a_command_that_starts_low_closes_high():
    """A gripper recorded as a command in [0, 1] where 1 closes: the demonstrations start at 0."""
    episodes = [np.r_[np.zeros(10), np.ones(10), np.zeros(5)] + 0.01 * k for k in range(6)]
    command = GripperCommand.from_demonstrations(np.concatenate(episodes), [e[0] for e in episodes])
    assert command.closed == "high" and command.is_closed(command.high) and not command.is_closed(command.low)
    assert [s.gripper_closed for s in stepped(command, [0.1, 0.9, 0.6, 0.2], observed=0.0)] == [
        False,
        True,
        True,
        False,
    ]
    assert GripperCommand.from_demonstrations(np.concatenate(episodes)).closed == "low"  # no starts: an opening's


def test_the_closed_value_travels_with_the_command_and_an_older_one_closes_low():
    command = GripperCommand.from_levels(0.0, 1.0, closed="high")
    assert GripperCommand.from_dict(command.to_dict()) == command
    older = {k: v for k, v in command.to_dict().items() if k != "closed"}
    assert GripperCommand.from_dict(older).closed == "low"
    with pytest.raises(PolicyError, match="closed value is 'low' or 'high'"):
        GripperCommand.from_dict({**command.to_dict(), "closed": "shut"})
    spec = replace(camera_spec(), gripper=command)
    assert PolicySpec.from_dict(spec.to_dict()).gripper.closed == "high"
    assert (
        Policy(ScriptedNetwork([[1, 0, 0]]), camera_spec(), mean_colour_features).step(observation(0)).gripper_closed
        is None
    )
