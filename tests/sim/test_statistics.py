"""A rate's Wilson 95% interval against hand-computed values and at its edges, and the behaviour entropy (D3IL's:
successful episodes only, normalised by the possible behaviours, averaged over scene contexts) on hand-made
choices."""

import math

import pytest

from cnep.sim.statistics import behaviour_entropy, normalised_entropy, wilson

FREE = ("left", "right")  # a scene that leaves both sides


@pytest.mark.parametrize(
    ("successes", "n", "expected"),
    [
        (5, 10, (0.2366, 0.7634)),  # p 0.5: centre 0.5, half z * sqrt(0.025 + z^2 / 400) / (1 + z^2 / 10)
        (46, 50, (0.8116, 0.9685)),  # 92%: shown as 92% [81-97]
        (0, 10, (0.0, 0.2775)),  # 0/n: [0, z^2 / (n + z^2)]
        (10, 10, (0.7225, 1.0)),  # n/n: [n / (n + z^2), 1]
        (1, 1, (0.2065, 1.0)),
    ],
)
def test_the_wilson_interval_matches_hand_computed_values(successes, n, expected):
    assert wilson(successes, n) == pytest.approx(expected, abs=1e-4)


def test_the_wilson_interval_is_exact_at_the_edges_and_narrows_with_more_episodes():
    assert wilson(0, 50)[0] == 0.0 and wilson(50, 50)[1] == 1.0
    assert wilson(0, 10)[1] == pytest.approx(1.959963984540054**2 / (10 + 1.959963984540054**2))
    wide, narrow = wilson(46, 50), wilson(460, 500)
    assert narrow[0] > wide[0] and narrow[1] < wide[1]


@pytest.mark.parametrize(("successes", "n"), [(1, 0), (3, 2), (-1, 4)])
def test_a_share_out_of_range_has_no_interval(successes, n):
    with pytest.raises(ValueError, match=f"{successes}/{n}"):
        wilson(successes, n)


def test_the_entropy_of_uniform_behaviours_is_one_and_of_one_behaviour_zero():
    assert behaviour_entropy([(FREE, "left"), (FREE, "right")] * 5) == 1.0
    assert behaviour_entropy([(FREE, "left")] * 7) == 0.0


def test_a_three_to_one_split_has_its_binary_entropy():
    h = -(0.75 * math.log2(0.75) + 0.25 * math.log2(0.25))  # 0.8113 bits of 1
    assert behaviour_entropy([(FREE, "left")] * 3 + [(FREE, "right")]) == round(h, 4) == 0.8113


def test_the_entropy_is_normalised_by_the_behaviours_possible_not_those_used():
    assert normalised_entropy(["a", "b"], possible=3) == pytest.approx(math.log(2) / math.log(3))
    assert behaviour_entropy([(("a", "b", "c"), "a"), (("a", "b", "c"), "b")]) == round(math.log(2) / math.log(3), 4)


def test_contexts_weigh_alike_and_a_context_with_one_valid_behaviour_has_no_entropy():
    grasp_y, grasp_x = ("left", "right"), ("far_left", "far_right")
    choices = [(grasp_y, "left"), (grasp_y, "right")] + [(grasp_x, "far_left")] * 6  # 1.0 and 0.0
    assert behaviour_entropy(choices) == 0.5  # not weighted by episodes (that would be 0.25)
    assert behaviour_entropy([*choices, (("left",), "left"), (("right",), "right")]) == 0.5
    assert behaviour_entropy([(("left",), "left"), (("right",), "left")]) is None
    assert behaviour_entropy([]) is None
    assert behaviour_entropy([(("right", "left"), "left"), (grasp_y, "right")]) == 1.0  # one context, either order


def test_a_behaviour_outside_its_scene_s_valid_ones_is_refused():
    with pytest.raises(ValueError, match="far_left"):
        behaviour_entropy([(FREE, "far_left")])
