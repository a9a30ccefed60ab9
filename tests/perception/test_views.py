"""Views of a demonstration's frames: seeded draws, kept per demonstration, within their bounds."""

import numpy as np
import pytest

from cnep.perception.constants import MAX_VIEWS
from cnep.perception.errors import PerceptionError
from cnep.perception.views import GAIN, OFFSET, SHIFT_PX, Views


def test_the_same_seed_and_demonstration_give_the_same_views_and_others_differ():
    assert Views(3, seed=0).of("demo-0") == Views(3, seed=0).of("demo-0")
    assert Views(3, seed=0).of("demo-0") != Views(3, seed=1).of("demo-0")
    assert Views(3, seed=0).of("demo-0") != Views(3, seed=0).of("demo-1")
    assert Views(2, seed=0).of("demo-0") == Views(3, seed=0).of("demo-0")[:2]  # one more view keeps the others
    for view in Views(MAX_VIEWS).of("demo-0"):
        assert abs(view.dx) <= SHIFT_PX and abs(view.dy) <= SHIFT_PX
        assert abs(view.gain - 1) <= GAIN and abs(view.offset) <= OFFSET


def test_a_view_moves_the_image_and_changes_its_light_alike_in_every_frame():
    frames = np.zeros((2, 32, 32, 3), dtype=np.uint8)
    frames[:, 10:20, 10:20] = 200  # a bright square on a dark table
    view = Views(1, seed=3).of("demo")[0]
    seen = view.apply(frames, first_step=0)
    assert seen.shape == frames.shape and seen.dtype == np.uint8
    rows, cols = np.nonzero(seen[0, :, :, 0] > 100)
    assert abs(cols.mean() - (14.5 + view.dx)) < 0.5 and abs(rows.mean() - (14.5 + view.dy)) < 0.5
    inside = seen[:, 14, 14].astype(float).mean(axis=-1)  # the square's centre, in both frames
    np.testing.assert_allclose(inside, 200 * view.gain + view.offset, atol=12)
    assert not np.array_equal(seen[0], seen[1])  # pixel noise is drawn per frame
    np.testing.assert_array_equal(view.apply(frames[1:], first_step=1)[0], seen[1])  # whatever the batch


@pytest.mark.parametrize("count", [-1, MAX_VIEWS + 1, 1.5, True])
def test_a_view_count_outside_its_range_is_refused(count):
    with pytest.raises(PerceptionError, match="--views must be a whole number from 0"):
        Views(count)
