import numpy as np
import pytest

from cnep.recordings import Event, RecordingError, add_events, read_events, read_trajectory, write_trajectory
from cnep.recordings.constants import TOPIC_EVENTS
from cnep.recordings.container import read_mcap
from tests.recordings.factories import trajectory_factory


def test_events_go_into_a_copy_and_read_back_in_time_order(tmp_path):
    traj = trajectory_factory(steps=8)
    src = write_trajectory(tmp_path / "t.mcap", traj)
    before = src.read_bytes()
    t = traj.timestamps_ns
    events = [
        Event(int(t[5]), {"kind": "expert_switch", "expert": "1"}),
        Event(int(t[0]), {"kind": "expert_switch", "expert": "0"}, duration_ns=int(t[5] - t[0])),
    ]
    dst = add_events(src, tmp_path / "with_events.mcap", events)
    assert src.read_bytes() == before
    assert read_events(src) == []
    assert read_events(dst) == sorted(events, key=lambda e: e.timestamp_ns)
    back = read_trajectory(dst)
    np.testing.assert_array_equal(back.data, traj.data)
    assert back.extractor == traj.extractor
    # file order is time order across topics
    times = [m.log_time for m in read_mcap(dst).messages]
    assert times == sorted(times)
    # events appended to a file that already has some
    more = add_events(dst, tmp_path / "more.mcap", [Event(int(t[7]), {"expert": "0"})])
    assert [e.timestamp_ns for e in read_events(more)] == [t[0], t[5], t[7]]
    assert len([c for c in read_mcap(more).channels.values() if c.topic == TOPIC_EVENTS]) == 1


def test_events_refuse_to_overwrite_the_input(tmp_path):
    src = write_trajectory(tmp_path / "t.mcap", trajectory_factory(steps=3))
    with pytest.raises(RecordingError, match="output is the input"):
        add_events(src, src, [Event(0, {})])


def test_event_validation():
    with pytest.raises(RecordingError, match=">= 0"):
        Event(-1, {})
    with pytest.raises(RecordingError, match="str to str"):
        Event(0, {"expert": 1})
