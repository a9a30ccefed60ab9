"""The pick-and-place closed loop: a scripted policy's episode judged by the physics and repeated exactly by its
seed, the switch after a change of the table, the rates, and a recording."""

import importlib.util

import numpy as np
import pytest

import cnep.sim

if not all(importlib.util.find_spec(name) for name in cnep.sim.EXTRA):
    pytest.skip("the sim extra is not installed", allow_module_level=True)

from cnep.pipeline.sim.pick_loop import evaluate_pick_policy  # noqa: E402
from cnep.pipeline.sim.pick_summary import pick_rates  # noqa: E402
from cnep.sim import PickPlaceEnv  # noqa: E402
from cnep.sim import pick_scene as P  # noqa: E402
from cnep.sim.pick_episode import first_switch, run_pick_episode  # noqa: E402
from tests.sim.pick_scripted import pick_policy  # noqa: E402


def test_a_few_closed_loop_steps_repeat_exactly_with_the_same_seed():
    env = PickPlaceEnv(P.FREE, max_steps=6)
    policy = pick_policy(gate=(0.1, 0.7, 0.1, 0.1))
    first, again, other = (run_pick_episode(env, policy, seed) for seed in (3, 3, 4))
    env.close()
    assert len(first.states) == 7 and not first.success and first.experts.tolist() == [1] * 6
    np.testing.assert_array_equal(first.states, again.states)
    np.testing.assert_array_equal(first.bar, again.bar)
    assert not np.array_equal(first.states[0], other.states[0])


@pytest.mark.slow
def test_a_closed_loop_episode_puts_the_bar_where_the_gate_says():
    env = PickPlaceEnv(P.FREE)
    seed = next(s for s in range(20) if env.reset(seed=s)[1]["orientation"] == "along_y")
    ep = run_pick_episode(env, pick_policy(gate=(0.1, 0.7, 0.1, 0.1)), seed)  # the right mat
    env.close()
    assert ep.success and ep.place == "right" and ep.lifted and not ep.collision
    assert ep.valid == ["left", "right"] and ep.switches == 0 and ep.change_step is None


def test_the_switch_step_is_the_first_change_of_expert_after_the_table_changed():
    experts = np.array([2, 2, 3, 2, 2, 0, 0, 1])
    assert first_switch(experts, 3) == 5
    assert first_switch(experts, 6) == 7
    assert first_switch(experts, None) is None
    assert first_switch(np.array([1, 1, 1]), 0) is None


def test_the_rates_count_places_and_switch_latency_over_the_changed_episodes():
    row = {"success": True, "collision": False, "lifted": True, "dropped": False, "switches": 1, "ms": {}}
    rows = [
        {**row, "place": "left", "change_step": 10, "switch_step": 12},
        {**row, "place": "right", "change_step": 10, "switch_step": 18},
        {**row, "success": False, "place": None, "change_step": 10, "switch_step": None},
    ]
    for r in rows:
        r["ms"] = {name: {"p50": 1.0, "p99": 2.0} for name in ("policy", "render", "physics")}
    rates = pick_rates(rows)
    assert rates["success"] == round(2 / 3, 4) and rates["places"] == {"left": 1, "right": 1}
    assert rates["switch_latency_p50"] == 5.0 and rates["switched_within"] == round(1 / 3, 4)


@pytest.mark.slow
def test_the_loop_runs_each_condition_and_records_the_first_episode(tmp_path, monkeypatch):
    monkeypatch.setenv("HOME", str(tmp_path))
    policy = pick_policy(gate=(0.4, 0.3, 0.2, 0.1))
    results = evaluate_pick_policy(policy, (P.CHANGED,), 1, label="scripted", record=1, recordings=tmp_path)
    assert results[P.CHANGED]["episodes"] == 1 and results[P.CHANGED]["switched_within"] is not None
    assert (tmp_path / "scripted-changed-seed0.rrd").stat().st_size > 0
