"""Whether a switch after a change counts: in pick-and-place the new expert's plan ends on a place valid after the
change, in the obstacle task it passes the box on the cue's side."""

import importlib.util

import numpy as np
import pytest

import cnep.sim

if not all(importlib.util.find_spec(name) for name in cnep.sim.EXTRA):
    pytest.skip("the sim extra is not installed", allow_module_level=True)

from cnep.sim.tasks.obstacle.switching import counted_switch as counted_cue_switch  # noqa: E402
from cnep.sim.tasks.obstacle.switching import side_of  # noqa: E402
from cnep.sim.tasks.pick_place import scene as P  # noqa: E402
from cnep.sim.tasks.pick_place.switching import counted_switch, plan_place  # noqa: E402

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
    beside[-1, 0] += P.mat_half(LEFT)[0] + 0.01  # just off the mat's long edge
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
