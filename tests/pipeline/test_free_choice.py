"""The demo's free-choice measures on hand-made cases: where motions end, and when a gate commits."""

import numpy as np
import pytest

from cnep.pipeline.demo.free_choice import PLACE_TOLERANCE, gate_commitment, place_outcomes
from cnep.pipeline.demo.scene import SLOT_XY

NEAR, FAR = np.asarray(SLOT_XY["near"]), np.asarray(SLOT_XY["far"])


def test_ends_in_a_slot_are_valid_and_the_average_of_the_two_is_not():
    ends = np.stack(
        [
            NEAR,
            NEAR + [0.0, 0.8 * PLACE_TOLERANCE],
            FAR + [0.03, 0.0],
            (NEAR + FAR) / 2,
            NEAR + [1.2 * PLACE_TOLERANCE, 0.0],
        ]
    )
    found = place_outcomes(ends)
    assert found["n"] == 5
    assert found["near"] == pytest.approx(2 / 5) and found["far"] == pytest.approx(1 / 5)
    assert found["valid"] == pytest.approx(3 / 5) and found["between"] == pytest.approx(2 / 5)
    midway = np.linalg.norm(NEAR - FAR) / 2  # ~0.19 m: the averaged motion is far from both slots
    expected = (0 + 0.8 * PLACE_TOLERANCE + 0.03 + midway + 1.2 * PLACE_TOLERANCE) / 5
    assert found["distance_m"] == pytest.approx(expected)


def test_no_motion_end_is_an_error():
    with pytest.raises(ValueError, match="at least one"):
        place_outcomes(np.zeros((0, 2)))


def test_a_gate_that_starts_split_and_commits():
    gates = np.array(
        [
            [0.48, 0.02, 0.47, 0.03],  # step 0: split between experts 0 and 2
            [0.60, 0.00, 0.40, 0.00],
            [0.40, 0.00, 0.60, 0.00],
            [0.05, 0.00, 0.95, 0.00],  # from here expert 2 holds p >= 0.9
            [0.01, 0.00, 0.99, 0.00],
        ]
    )
    found = gate_commitment(gates)
    assert [e for e, _ in found["start"]] == [0, 2]
    assert found["start"][0][1] == pytest.approx(0.48) and found["start"][1][1] == pytest.approx(0.47)
    assert found["expert"] == 2 and found["step"] == 3


def test_a_gate_that_dips_below_the_threshold_commits_after_the_dip_and_one_that_never_holds_does_not():
    held = np.array([[0.0, 1.0], [0.0, 1.0], [0.2, 0.8], [0.0, 1.0]])
    assert gate_commitment(held)["step"] == 3
    assert gate_commitment(np.array([[0.5, 0.5], [0.3, 0.7]]))["step"] is None
    assert gate_commitment(np.array([[0.05, 0.95], [0.0, 1.0]]))["step"] == 0
