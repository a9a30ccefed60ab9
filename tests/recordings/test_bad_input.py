"""Every kind of bad input gives one RecordingError naming the file, and leaves the input untouched."""

import dataclasses

import numpy as np
import pytest
from mcap.reader import make_reader
from mcap.writer import Writer

from cnep.recordings import (
    Demonstration,
    Episode,
    RecordingError,
    Trajectory,
    read_demonstration,
    read_trajectory,
    write_demonstration,
    write_trajectory,
)
from cnep.recordings.constants import TOPIC_GRIPPER, TOPIC_TRAJECTORY
from cnep.recordings.container import read_mcap
from cnep.recordings.schemas import encode_vector
from tests.recordings.factories import demonstration_factory, jpeg_frames, trajectory_factory


def write_raw(path, contents, messages, metadata=None, channel_metadata=None):
    """Write `messages` in the given order (no sorting, no validation) with the schemas of `contents`."""
    with open(path, "wb") as f:
        w = Writer(f)
        w.start()
        for name, data in (metadata or contents.metadata).items():
            w.add_metadata(name, data)
        sid = {k: w.register_schema(s.name, s.encoding, s.data) for k, s in contents.schemas.items()}
        cid = {
            k: w.register_channel(
                c.topic, c.message_encoding, sid[c.schema_id], (channel_metadata or {}).get(c.topic, c.metadata)
            )
            for k, c in contents.channels.items()
        }
        for m in messages:
            w.add_message(cid[m.channel_id], m.log_time, m.data, m.publish_time)
        w.finish()
    return path


@pytest.fixture
def traj_file(tmp_path):
    return write_trajectory(tmp_path / "traj.mcap", trajectory_factory(steps=30, features=False))


@pytest.fixture
def demo_file(tmp_path):
    return write_demonstration(tmp_path / "demo.mcap", demonstration_factory(steps=30))


def expect_error(read, path, *words):
    before = path.read_bytes()
    with pytest.raises(RecordingError) as info:
        read(path)
    msg = str(info.value)
    assert str(path) in msg and "\n" not in msg
    for w in words:
        assert w in msg, msg
    assert path.read_bytes() == before
    return msg


def test_zero_byte_file(tmp_path):
    (tmp_path / "empty.mcap").write_bytes(b"")
    expect_error(read_trajectory, tmp_path / "empty.mcap", "empty file")


def test_missing_file(tmp_path):
    with pytest.raises(RecordingError, match="no such file"):
        read_demonstration(tmp_path / "nope.mcap")


def test_not_an_mcap(tmp_path):
    (tmp_path / "notes.mcap").write_text("Time,p_x\n0,1\n")
    expect_error(read_demonstration, tmp_path / "notes.mcap", "not an MCAP file")


@pytest.mark.parametrize("keep", [0.3, 0.6, 0.95])
def test_truncated(traj_file, keep):
    data = traj_file.read_bytes()
    traj_file.write_bytes(data[: int(len(data) * keep)])
    salvageable = bool(read_mcap(traj_file, salvage=True).messages)  # what `cnep repair` would find
    msg = expect_error(read_trajectory, traj_file, "truncated")
    assert ("cnep repair" in msg) == salvageable and ("nothing can be salvaged" in msg) == (not salvageable)


def chunk_offsets(path):
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    return [(c.chunk_start_offset, c.chunk_length) for c in summary.chunk_indexes]


@pytest.mark.parametrize("fixture", ["traj_file", "demo_file"])
def test_flipped_byte_inside_a_chunk(request, fixture):
    path = request.getfixturevalue(fixture)
    start, length = chunk_offsets(path)[0]
    data = bytearray(path.read_bytes())
    data[start + length // 2] ^= 0x40
    path.write_bytes(bytes(data))
    read = read_trajectory if fixture == "traj_file" else read_demonstration
    expect_error(read, path, "corrupt")


def test_flipped_byte_in_metadata_is_caught_by_the_data_crc(traj_file):
    data = bytearray(traj_file.read_bytes())
    pos = data.index(b"synthetic")  # the `source` value of the episode record
    data[pos] ^= 0x01
    traj_file.write_bytes(bytes(data))
    expect_error(read_trajectory, traj_file, "corrupt")


def test_missing_topic(demo_file, tmp_path):
    contents = read_mcap(demo_file)
    gripper = contents.channel_of_topic(TOPIC_GRIPPER).id
    contents.channels.pop(gripper)
    out = write_raw(tmp_path / "no_gripper.mcap", contents, [m for m in contents.messages if m.channel_id != gripper])
    expect_error(read_demonstration, out, "missing topic '/gripper'", "/ee/pose")


def test_wrong_kind(demo_file):
    expect_error(read_trajectory, demo_file, "'demonstration' file", "expected a 'trajectory'")


def replace_message(contents, step, data=None, log_time=None):
    ch = contents.channel_of_topic(TOPIC_TRAJECTORY).id
    msgs = [m for m in contents.messages if m.channel_id == ch]
    new = dataclasses.replace(
        msgs[step], data=data or msgs[step].data, log_time=msgs[step].log_time if log_time is None else log_time
    )
    return [new if m is msgs[step] else m for m in contents.messages]


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_non_finite_values_in_a_file(traj_file, tmp_path, bad):
    contents = read_mcap(traj_file)
    row = np.zeros(8, np.float32)
    row[6], row[7] = 1.0, bad
    t = contents.messages[-1].log_time
    out = write_raw(tmp_path / "nan.mcap", contents, replace_message(contents, -1, encode_vector(t, row)))
    expect_error(read_trajectory, out, "non-finite")


def test_timestamps_backwards_in_a_file(traj_file, tmp_path):
    contents = read_mcap(traj_file)
    out = write_raw(tmp_path / "back.mcap", contents, replace_message(contents, 10, log_time=0))
    expect_error(read_trajectory, out, "backwards", "step 10")


def test_wrong_vector_width_in_a_message(traj_file, tmp_path):
    contents = read_mcap(traj_file)
    t = contents.messages[-1].log_time
    out = write_raw(
        tmp_path / "w.mcap", contents, replace_message(contents, 5, encode_vector(t, np.ones(7, np.float32)))
    )
    expect_error(read_trajectory, out, "wrong vector width 7 at step 5")


def test_wrong_width_in_the_layout(traj_file, tmp_path):
    contents = read_mcap(traj_file)
    meta = dict(contents.channel_of_topic(TOPIC_TRAJECTORY).metadata, width="9")
    out = write_raw(tmp_path / "l.mcap", contents, contents.messages, channel_metadata={TOPIC_TRAJECTORY: meta})
    expect_error(read_trajectory, out, "width 9 is not a known layout")


def test_unknown_format_version(traj_file, tmp_path):
    contents = read_mcap(traj_file)
    meta = {**contents.metadata, "episode": {**contents.metadata["episode"], "format_version": "99"}}
    out = write_raw(tmp_path / "v.mcap", contents, contents.messages, metadata=meta)
    expect_error(read_trajectory, out, "unknown format_version '99'", "Upgrade")


def test_foreign_mcap_without_episode(traj_file, tmp_path):
    contents = read_mcap(traj_file)
    out = write_raw(tmp_path / "foreign.mcap", contents, contents.messages, metadata={"other": {"a": "b"}})
    expect_error(read_trajectory, out, "not written by cnep", "cnep ingest")


# --- validation of records in memory ---------------------------------------------------------------


def demo_kwargs(steps=5):
    d = demonstration_factory(steps=steps, frames=False)
    return {"episode": d.episode, "timestamps_ns": d.timestamps_ns, "pose": d.pose, "gripper": d.gripper}


@pytest.mark.parametrize(
    "change,words",
    [
        (lambda k: k.update(timestamps_ns=k["timestamps_ns"][::-1].copy()), "backwards"),
        (lambda k: k.update(timestamps_ns=k["timestamps_ns"] * 0), "backwards"),
        (lambda k: k.update(timestamps_ns=k["timestamps_ns"] - 2 * 10**18), "negative"),
        (lambda k: k.update(timestamps_ns=k["timestamps_ns"].astype(float)), "integer nanoseconds"),
        (lambda k: k["pose"].__setitem__((2, 1), np.nan), "non-finite"),
        (lambda k: k["gripper"].__setitem__(3, np.inf), "non-finite"),
        (lambda k: k.update(pose=k["pose"][:, :6]), "shape (5, 7)"),
        (lambda k: k["pose"].__setitem__((1, slice(3, 7)), 0.0), "zero length"),
        (lambda k: k.update(frames=[b"\xff\xd8x"] * 4), "4 frames for 5 steps"),
        (lambda k: k.update(frames=[b"\x89PNG"] * 5), "not JPEG"),
    ],
)
def test_demonstration_validation(change, words):
    kwargs = demo_kwargs()
    change(kwargs)
    with pytest.raises(RecordingError, match=words.replace("(", r"\(").replace(")", r"\)")):
        Demonstration(**kwargs)


def test_trajectory_validation():
    ep = Episode("e", fps=10)
    ts = np.arange(3)
    motion = np.tile(np.array([0, 0, 0, 0, 0, 0, 1, 0], np.float32), (3, 1))
    with pytest.raises(RecordingError, match="width 9 is not a known layout"):
        Trajectory(ep, ts, np.zeros((3, 9)))
    with pytest.raises(RecordingError, match="needs the feature extractor"):
        Trajectory(ep, ts, np.concatenate([np.zeros((3, 1280)), motion], axis=1))
    with pytest.raises(RecordingError, match="no feature block"):
        Trajectory(ep, ts, motion, extractor={"architecture": "x"})
    with pytest.raises(RecordingError, match="does not match"):
        Trajectory(ep, ts, motion, blocks={"pose_xyz": (0, 3), "pose_quat_xyzw": (3, 7), "grip": (7, 8)})
    with pytest.raises(RecordingError, match="shape"):
        Trajectory(ep, ts, motion[:2])


@pytest.mark.parametrize(
    "kwargs,words",
    [
        ({"episode_id": "", "fps": 1}, "non-empty"),
        ({"episode_id": "e", "fps": 0}, "> 0 Hz"),
        ({"episode_id": "e", "fps": float("nan")}, "> 0 Hz"),
        ({"episode_id": "e", "fps": 1, "extra": {"kind": "x"}}, "reserved"),
    ],
)
def test_episode_validation(kwargs, words):
    with pytest.raises(RecordingError, match=words):
        Episode(**kwargs)


def test_writer_rejects_backwards_step_and_mixed_frames(tmp_path):
    from cnep.recordings import DemonstrationWriter

    demo = demonstration_factory(steps=3, frames=False)
    with pytest.raises(RecordingError, match="backwards"), DemonstrationWriter(tmp_path / "d.mcap", demo.episode) as w:
        w.write_step(10, demo.pose[0], 0.0)
        w.write_step(5, demo.pose[1], 0.0)
    with (
        pytest.raises(RecordingError, match="at every step or at none"),
        DemonstrationWriter(tmp_path / "d.mcap", demo.episode) as w,
    ):
        w.write_step(1, demo.pose[0], 0.0, jpeg_frames(1)[0])
        w.write_step(2, demo.pose[1], 0.0)
    with pytest.raises(RecordingError, match="no steps"), DemonstrationWriter(tmp_path / "d.mcap", demo.episode):
        pass
    assert list(tmp_path.iterdir()) == []
