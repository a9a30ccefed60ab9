"""Which free-choice episode the demo replays (on hand-made gate traces), and that nothing before the carry
shows the demonstrator's pick."""

import numpy as np
import pytest

from cnep.pipeline.demo.free_choice import COMMIT_GATE, SPLIT_GATE, gate_census, replay_pick, starts_split
from cnep.pipeline.demo.generator import CHOICE_KEY, CHOICE_STEP_KEY, make_free_choice


def _trace(first: list[float], last: list[float], steps: int = 6) -> np.ndarray:
    """(steps, 4) gate rows going linearly from `first` to `last` (each a distribution over 4 experts)."""
    w = np.linspace(0.0, 1.0, steps)[:, None]
    return (1 - w) * np.asarray(first) + w * np.asarray(last)


CONFIDENT = _trace([0.98, 0.02, 0.0, 0.0], [1.0, 0.0, 0.0, 0.0])  # commits from step 0: not split
SPLIT_NEVER_COMMITS = _trace([0.5, 0.5, 0.0, 0.0], [0.6, 0.4, 0.0, 0.0])  # the least certain start of all
SPLIT_COMMITS = _trace([0.0, 0.0, 0.6, 0.4], [0.0, 0.0, 0.0, 1.0])  # split, then expert 3 holds p >= 0.9
LESS_SPLIT_COMMITS = _trace([0.65, 0.35, 0.0, 0.0], [0.0, 1.0, 0.0, 0.0])


def test_the_thresholds_mean_what_the_rule_says():
    assert starts_split(SPLIT_COMMITS) and not starts_split(CONFIDENT)
    assert not starts_split(_trace([SPLIT_GATE, 1 - SPLIT_GATE, 0, 0], [1, 0, 0, 0]))  # at the threshold: not split
    assert SPLIT_GATE < COMMIT_GATE


def test_the_replay_picks_the_least_certain_start_among_gates_that_start_split_and_commit():
    traces = [CONFIDENT, LESS_SPLIT_COMMITS, SPLIT_NEVER_COMMITS, SPLIT_COMMITS]
    assert replay_pick(traces) == 3  # 0.60 at step 0 beats 0.65; the 0.50 start never commits
    assert gate_census(traces) == {"n": 4, "split": 3, "split_commit": 2}


def test_without_such_a_gate_the_replay_picks_the_least_certain_start_and_ties_go_first():
    assert replay_pick([CONFIDENT, SPLIT_NEVER_COMMITS, CONFIDENT]) == 1
    assert replay_pick([CONFIDENT, CONFIDENT]) == 0
    assert replay_pick([SPLIT_COMMITS, SPLIT_COMMITS]) == 0
    assert gate_census([CONFIDENT]) == {"n": 1, "split": 0, "split_commit": 0}
    with pytest.raises(ValueError, match="at least one"):
        replay_pick([])


class _ForcedPick:
    """A numpy Generator whose first `integers` draw (the demonstrator's pick) is replaced by `pick`; every
    draw, that one included, still advances the real generator, so the rest of the stream is unchanged."""

    def __init__(self, seed: int, pick: int) -> None:
        self._rng, self._pick = np.random.default_rng(seed), pick

    def integers(self, *args, **kwargs):
        drawn = self._rng.integers(*args, **kwargs)
        if self._pick is None:
            return drawn
        pick, self._pick = self._pick, None
        return pick

    def __getattr__(self, name):
        return getattr(self._rng, name)


@pytest.mark.parametrize("side", ["left", "right"])
def test_nothing_before_the_carry_shows_the_pick(side):
    """The same episode with either pick: byte-equal frames and equal poses up to the carry, then they part.

    So a model conditioned on the first steps of a held-out free-choice scene cannot know the pick.
    """
    near, far = (make_free_choice(side, 24, 10.0, _ForcedPick(7, pick), "x") for pick in (0, 1))
    assert (near.episode.extra[CHOICE_KEY], far.episode.extra[CHOICE_KEY]) == ("near", "far")
    carry = int(near.episode.extra[CHOICE_STEP_KEY])
    assert carry == int(far.episode.extra[CHOICE_STEP_KEY]) and 0 < carry < 23
    assert near.frames[: carry + 1] == far.frames[: carry + 1]
    np.testing.assert_array_equal(near.pose[: carry + 1], far.pose[: carry + 1])
    np.testing.assert_array_equal(near.gripper[: carry + 1], far.gripper[: carry + 1])
    assert np.linalg.norm(near.pose[-1, :2] - far.pose[-1, :2]) > 0.2  # then each goes to its own slot
