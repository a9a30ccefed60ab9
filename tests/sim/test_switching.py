"""Whether a switch after a change counts: in pick-and-place the new expert's plan ends on a place valid after the
change, in the obstacle task it passes the box on the cue's side; an episode records the places valid after the
change and the switch that counts."""

import importlib.util

import numpy as np
import pytest

import cnep.sim

if not all(importlib.util.find_spec(name) for name in cnep.sim.EXTRA):
    pytest.skip("the sim extra is not installed", allow_module_level=True)

from cnep.runtime import STATE_NAMES, PolicyStep  # noqa: E402
from cnep.sim.episode import ONLINE, run_episode  # noqa: E402
from cnep.sim.tasks.obstacle.switching import counted_switch as counted_cue_switch  # noqa: E402
from cnep.sim.tasks.obstacle.switching import side_of  # noqa: E402
from cnep.sim.tasks.pick_place import scene as P  # noqa: E402
from cnep.sim.tasks.pick_place.demonstrator import pick_expert  # noqa: E402
from cnep.sim.tasks.pick_place.env import PickPlaceEnv  # noqa: E402
from cnep.sim.tasks.pick_place.switching import counted_switch, plan_place, rerouted  # noqa: E402

LEFT, RIGHT, FAR_LEFT = 0, 1, 2  # indices of P.PLACES


def _plan_to(place: int | None, waypoints: int = 5) -> np.ndarray:
    """A plan (waypoints, 3) from the bar to `place`'s mat (None: to the table's middle, no mat), in m."""
    end = np.array([0.0, 0.0]) if place is None else np.asarray(P.PLACES[place][1])
    xy = np.linspace([0.0, -0.08], end, waypoints)
    return np.column_stack([xy, np.full(waypoints, 0.2)])


def test_a_plans_place_is_the_mat_under_its_end():
    assert plan_place(_plan_to(RIGHT)) == RIGHT and plan_place(_plan_to(FAR_LEFT)) == FAR_LEFT
    assert plan_place(_plan_to(None)) is None
    beside = _plan_to(LEFT)
    beside[-1, 0] += P.BAR.place_half(LEFT)[0] + 0.01  # just off the mat's long edge
    assert plan_place(beside) is None


def test_only_a_switch_after_the_change_to_a_valid_places_plan_counts():
    # Reads at steps 0-7: heading right, the table changes before step 3 acts (right taken, left valid after).
    experts = np.array([1, 1, 1, 1, 2, 2, 0, 0])
    predicted = np.stack([_plan_to(RIGHT)] * 4 + [_plan_to(FAR_LEFT)] * 2 + [_plan_to(LEFT)] * 2)
    assert counted_switch(experts, predicted, 3, [LEFT]) == 6  # the switch at step 4 went to a place of no use
    assert counted_switch(experts, predicted, 3, [FAR_LEFT, LEFT]) == 4
    assert counted_switch(experts, predicted, 6, [LEFT]) is None  # switches the read of step 6 made are not after it
    assert counted_switch(experts, predicted, None, [LEFT]) is None  # no change, nothing to count
    assert counted_switch(experts[:1], predicted[:1], 0, [LEFT]) is None  # one read (planned): no switch


def test_a_re_route_is_the_first_plan_after_the_change_to_a_valid_place_whichever_expert_made_it():
    # One expert covers two places: after the change its plan moves from right to left through the middle, no switch.
    predicted = np.stack([_plan_to(RIGHT)] * 4 + [_plan_to(None)] * 2 + [_plan_to(LEFT)] * 2)
    experts = np.zeros(len(predicted), dtype=int)
    assert counted_switch(experts, predicted, 3, [LEFT]) is None and rerouted(predicted, 3, [LEFT]) == 6
    assert rerouted(predicted, 3, [FAR_LEFT]) is None  # its plan never ends there
    assert rerouted(predicted, 6, [LEFT]) == 7  # the read of the change's step is not after it
    assert rerouted(predicted, None, [LEFT]) is None


def test_a_path_passes_on_the_side_of_the_box_it_is_on_where_it_comes_nearest_the_boxs_y():
    ys = np.linspace(-0.3, 0.3, 7)
    path = np.column_stack([0.2 * np.sin(np.pi * (ys + 0.3) / 0.6), ys])  # bulges to +x at y = 0
    assert side_of(path, np.array([0.0, 0.0])) == "right"
    assert side_of(path, np.array([0.25, 0.0])) == "left"  # the box moved past the bulge


def test_only_a_switch_after_the_cue_to_a_plan_passing_on_its_side_counts():
    ys = np.linspace(-0.3, 0.3, 7)
    left, right = (np.column_stack([sign * 0.2 * np.cos(ys * 5), ys]) for sign in (-1, 1))
    experts = np.array([0, 0, 1, 1, 0, 0])
    predicted = np.stack([right, right, left, left, right, right])
    box = np.array([0.0, 0.0])
    assert counted_cue_switch(experts, predicted, 1, "left", box) == 2
    assert counted_cue_switch(experts, predicted, 1, "right", box) == 4
    assert counted_cue_switch(experts, predicted, None, "left", box) is None


class _Recorded(PickPlaceEnv):
    """The pick-and-place environment keeping its last info for the demonstrator behind the policy's interface."""

    def reset(self, **kwargs):
        observation, self.last_info = super().reset(**kwargs)
        return observation, self.last_info

    def step(self, action):
        *rest, self.last_info = super().step(action)
        return (*rest, self.last_info)


class _ExpertPolicy:
    """The closed-loop demonstrator as a policy: its next waypoint first, the rest of its plan the prediction (held
    at its end, as many waypoints as the episode's steps), the place it heads for the active expert."""

    action_names, gripper = STATE_NAMES, None

    def __init__(self, env: _Recorded) -> None:
        self.env = env

    def reset(self, seed: int) -> None:
        self.expert, self.k = pick_expert(self.env, self.env.last_info, np.random.default_rng(seed)), 0

    def step(self, observation: dict) -> PolicyStep:
        action = self.expert.action(self.env.last_info)
        plan = np.vstack([action, self.expert.plan.waypoints[self.expert.plan.given :]])
        plan = np.vstack([plan, np.repeat(plan[-1:], self.env.max_steps - len(plan), axis=0)])  # W: held at its end
        places = np.eye(len(P.PLACES))
        self.k += 1
        return PolicyStep(self.k - 1, 0.0, 0.0, plan, np.zeros_like(plan), np.zeros(len(plan)),
                          places[self.expert.draw.place], self.expert.draw.place, None)  # fmt: skip


def test_an_episode_records_the_places_valid_after_the_change_and_the_switch_to_one():
    env = _Recorded(P.CHANGED, version=1, frames=False)
    ep = run_episode(env, _ExpertPolicy(env), seed=3, protocol=ONLINE)
    assert ep.success and ep.change_step is not None
    assert ep.valid_after_change == ep.valid and ep.place in ep.valid_after_change
    assert ep.switch_step == ep.valid_switch_step == ep.reroute_step == ep.change_step + 1  # at its next read
    env.close()
