"""The pick-and-place closed loop: a scripted policy's episode judged by the physics and repeated exactly by its
seed, by both protocols (the planned one reads the policy once and executes its plan), the step limit, the switch
after a change of the table, the rates, the table, and a recording per protocol."""

import importlib.util
from dataclasses import replace

import numpy as np
import pytest

import cnep.sim

if not all(importlib.util.find_spec(name) for name in cnep.sim.EXTRA):
    pytest.skip("the sim extra is not installed", allow_module_level=True)

from cnep.outputs import writing_as  # noqa: E402
from cnep.pipeline.sim.config import LoopSettings  # noqa: E402
from cnep.pipeline.sim.loop import evaluate_policy  # noqa: E402
from cnep.pipeline.sim.summary import format_table  # noqa: E402
from cnep.sim import PickPlaceEnv  # noqa: E402
from cnep.sim.episode import (  # noqa: E402
    ONLINE,
    PLANNED,
    Driver,
    run_episode,  # noqa: E402
)
from cnep.sim.tasks import find_task  # noqa: E402
from cnep.sim.tasks.pick_place import scene as P  # noqa: E402
from cnep.sim.tasks.pick_place.scoring import (
    pick_rates,  # noqa: E402
    switch_after,  # noqa: E402
)
from tests.sim.pick_scripted import pick_policy  # noqa: E402


def test_a_few_closed_loop_steps_repeat_exactly_with_the_same_seed():
    env = PickPlaceEnv(P.FREE, max_steps=6)
    policy = pick_policy(gate=(0.1, 0.7, 0.1, 0.1))
    first, again, other = (run_episode(env, policy, seed) for seed in (3, 3, 4))
    env.close()
    assert len(first.states) == 7 and not first.success and first.experts.tolist() == [1] * 6
    np.testing.assert_array_equal(first.states, again.states)
    np.testing.assert_array_equal(first.object_poses, again.object_poses)
    assert not np.array_equal(first.states[0], other.states[0])


def test_the_planned_protocol_reads_the_policy_once_and_executes_its_waypoints_in_turn():
    env = PickPlaceEnv(P.FREE, max_steps=6)
    observation, _ = env.reset(seed=3)
    policy = pick_policy(gate=(0.1, 0.7, 0.1, 0.1), waypoints=4)
    policy.reset(seed=3)
    planned, online = Driver(policy, PLANNED, observation), Driver(policy, ONLINE, observation)
    actions = [planned.action(observation, k) for k in range(6)]
    assert len(planned.experts) == 1  # one read, at step 0
    plan = planned.predicted[0]  # (4, 3): the waypoints' xyz
    for k, action in enumerate(actions):
        np.testing.assert_allclose(action[:3], plan[min(k, 3)], rtol=1e-6)  # held at the last waypoint
    assert not np.allclose(actions[0][:3], actions[3][:3])
    policy.reset(seed=3)
    for k in range(3):
        online.action(observation, k)
    assert len(online.experts) == 3  # a read per step
    with pytest.raises(ValueError, match="protocol must be one of planned, online"):
        Driver(policy, "replanned", observation)
    ep = run_episode(env, pick_policy(gate=(0.1, 0.7, 0.1, 0.1), waypoints=P.MAX_STEPS), 3, PLANNED)
    env.close()
    assert ep.protocol == PLANNED and len(ep.states) == 7 and ep.experts.tolist() == [1] and len(ep.policy_s) == 1
    assert ep.gates.shape == (1, 4) and ep.predicted.shape == (1, P.MAX_STEPS, 3) and ep.switches == 0


def test_the_driver_executes_the_policys_gripper_command_as_the_environment_closes_and_opens_it():
    env = PickPlaceEnv(P.FREE, max_steps=P.MAX_STEPS, frames=False)
    observation, _ = env.reset(seed=3)
    env.close()
    wide = P.CLOSE_BELOW + 0.003  # closed on a wider object, the recordings read more than the environment closes below
    grippers = {}
    for states in (None, (0.0, P.FINGER_OPEN)):
        policy = pick_policy(gate=(0.1, 0.7, 0.1, 0.1), waypoints=P.MAX_STEPS, closed=wide)
        policy.reset(seed=3)
        driver = Driver(policy, PLANNED, observation, states)
        grippers[states] = {round(float(driver.action(observation, k)[7]), 4) for k in range(P.MAX_STEPS)}
    assert grippers[None] == {round(wide, 4), P.FINGER_OPEN}  # the command's own values: the environment would open
    assert grippers[(0.0, P.FINGER_OPEN)] == {0.0, P.FINGER_OPEN}  # a two-state gripper's: closed squeezes


@pytest.mark.slow
def test_a_planned_episode_puts_the_bar_where_its_one_read_says(monkeypatch):
    env = PickPlaceEnv(P.FREE)
    seed = next(s for s in range(20) if env.reset(seed=s)[1]["orientation"] == "along_y")
    policy = pick_policy(gate=(0.1, 0.7, 0.1, 0.1), waypoints=P.MAX_STEPS)  # the right mat
    reads = []
    step = policy.step
    monkeypatch.setattr(policy, "step", lambda observation: reads.append(observation) or step(observation))
    ep = run_episode(env, policy, seed, PLANNED)
    env.close()
    assert ep.success and ep.place == "right" and ep.lifted and not ep.collision
    assert len(reads) == 1 and len(ep.states) > 2 and ep.switches == 0


@pytest.mark.slow
def test_a_closed_loop_episode_puts_the_bar_where_the_gate_says():
    env = PickPlaceEnv(P.FREE)
    seed = next(s for s in range(20) if env.reset(seed=s)[1]["orientation"] == "along_y")
    ep = run_episode(env, pick_policy(gate=(0.1, 0.7, 0.1, 0.1)), seed)  # the right mat
    env.close()
    assert ep.success and ep.place == "right" and ep.lifted and not ep.collision
    assert ep.valid == ["left", "right"] and ep.switches == 0 and ep.change_step is None


def test_the_switch_step_is_the_first_change_of_expert_after_the_table_changed():
    experts = np.array([2, 2, 3, 2, 2, 0, 0, 1])
    assert switch_after(experts, 3) == 5
    assert switch_after(experts, 6) == 7
    assert switch_after(experts, None) is None
    assert switch_after(np.array([1, 1, 1]), 0) is None


def test_the_rates_count_places_and_switch_latency_over_the_changed_episodes():
    row = {"success": True, "collision": False, "lifted": True, "dropped": False, "switches": 1, "ms": {}}
    rows = [
        {
            **row,
            "place": "left",
            "valid": ["left"],
            "change_step": 10,
            "first_switch_step": 12,
            "valid_switch_step": 12,
        },
        {
            **row,
            "place": "right",
            "valid": ["right"],
            "change_step": 10,
            "first_switch_step": 18,
            "valid_switch_step": 18,
        },
        {
            **row,
            "success": False,
            "place": None,
            "valid": ["left"],
            "change_step": 10,
            "first_switch_step": None,
            "valid_switch_step": None,
        },
    ]
    for r in rows:
        r["ms"] = {name: {"p50": 1.0, "p99": 2.0} for name in ("policy", "render", "physics")}
    rates = pick_rates(rows)
    assert rates["success"] == round(2 / 3, 4) and rates["places"] == {"left": 1, "right": 1}
    assert rates["switch_latency_p50"] == 5.0 and rates["switched_within"] == round(1 / 3, 4)
    assert rates["entropy"] is None  # a changed scene leaves one valid place


def test_the_step_limit_truncates_the_episodes_of_either_protocol():
    policy = pick_policy(gate=(0.1, 0.7, 0.1, 0.1), waypoints=P.MAX_STEPS)  # its plan spans the whole task
    task = replace(find_task("pick-place", 0), conditions=(P.FREE,))
    results = evaluate_policy(policy, task, LoopSettings(episodes=2, max_steps=5), label="scripted")
    for protocol in (PLANNED, ONLINE):
        rows = results[protocol][P.FREE]["per_episode"]
        assert [(row["steps"], row["success"]) for row in rows] == [(5, False), (5, False)]


@pytest.mark.slow
def test_the_loop_runs_each_protocol_and_condition_and_records_the_first_episode(tmp_path, monkeypatch):
    monkeypatch.setenv("HOME", str(tmp_path))
    policy = pick_policy(gate=(0.4, 0.3, 0.2, 0.1), waypoints=P.MAX_STEPS)
    task = replace(find_task("pick-place", 0), conditions=(P.CHANGED,))
    settings = LoopSettings(episodes=1, max_steps=P.MAX_STEPS, record=1)
    with writing_as("sim eval"):  # a recording is the command's output, named in its folder's record
        results = evaluate_policy(policy, task, settings, label="scripted", recordings=tmp_path)
    assert list(results) == [PLANNED, ONLINE]
    planned, online = results[PLANNED][P.CHANGED], results[ONLINE][P.CHANGED]
    assert planned["episodes"] == online["episodes"] == 1
    assert planned["per_episode"][0]["change_step"] is not None  # the table changed under the plan too
    assert planned["switching"] == 0 and planned["switched_within"] == 0 and planned["switch_latency_p50"] is None
    assert online["switched_within"] is not None
    for protocol in (PLANNED, ONLINE):
        assert (tmp_path / f"scripted-{protocol}-changed-seed0.rrd").stat().st_size > 0
    lines = format_table({"scripted-seed0": results}, task).splitlines()
    assert lines[0].split()[:3] == ["policy", "protocol", "condition"] and len(lines) == 4
    assert lines[2].split()[:3] == ["scripted-seed0", PLANNED, P.CHANGED]
    assert lines[3].split()[:3] == ["scripted-seed0", ONLINE, P.CHANGED]
