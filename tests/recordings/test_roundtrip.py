import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from cnep import recordings
from cnep.recordings import (
    BLOCKS_FULL,
    BLOCKS_MOTION,
    DemonstrationReader,
    DemonstrationWriter,
    Episode,
    Trajectory,
    TrajectoryReader,
    TrajectoryWriter,
    read_demonstration,
    read_trajectory,
    write_demonstration,
    write_trajectory,
)
from cnep.recordings.constants import METADATA_STEPS, TOPIC_GRIPPER, TOPIC_IMAGE, TOPIC_POSE
from cnep.recordings.container import read_mcap
from tests.recordings.factories import demonstration_factory, random_pose, trajectory_factory


def assert_same_demo(a, b):
    assert a.episode == b.episode
    np.testing.assert_array_equal(a.timestamps_ns, b.timestamps_ns)
    np.testing.assert_array_equal(a.pose, b.pose)
    np.testing.assert_array_equal(a.gripper, b.gripper)
    assert a.frames == b.frames
    assert a.attachments == b.attachments


def test_public_api_is_importable():
    for name in recordings.__all__:
        assert getattr(recordings, name) is not None


@pytest.mark.parametrize("frames", [True, False])
def test_demonstration_round_trip(tmp_path, frames):
    demo = demonstration_factory(steps=15, frames=frames)
    path = write_demonstration(tmp_path / "d.mcap", demo)
    back = read_demonstration(path)
    assert_same_demo(demo, back)
    assert back.has_frames is frames
    contents = read_mcap(path)
    topics = {c.topic for c in contents.channels.values()}
    assert topics == ({TOPIC_POSE, TOPIC_GRIPPER} | ({TOPIC_IMAGE} if frames else set()))
    assert contents.metadata[METADATA_STEPS]["n_steps"] == "15"
    assert contents.metadata["episode"]["format_version"] == recordings.FORMAT_VERSION


@pytest.mark.parametrize("features,frames", [(True, False), (False, False), (True, True)])
def test_trajectory_round_trip(tmp_path, features, frames):
    traj = trajectory_factory(steps=12, features=features, frames=frames)
    back = read_trajectory(write_trajectory(tmp_path / "t.mcap", traj))
    np.testing.assert_array_equal(back.data, traj.data)
    np.testing.assert_array_equal(back.timestamps_ns, traj.timestamps_ns)
    assert back.blocks == dict(BLOCKS_FULL if features else BLOCKS_MOTION)
    assert back.extractor == traj.extractor
    assert back.episode == traj.episode
    assert back.frames == traj.frames
    assert back.width == (1288 if features else 8)
    assert (back.features is not None) is features
    assert back.views is None


def test_a_trajectory_s_feature_views_round_trip_and_a_wrong_shape_is_refused(tmp_path):
    traj = trajectory_factory(steps=7)
    views = np.random.default_rng(3).normal(size=(3, 7, 1280)).astype(np.float32)
    viewed = Trajectory.from_demonstration(demonstration_factory(7), traj.features, traj.extractor, views=views)
    path = write_trajectory(tmp_path / "t.mcap", viewed)
    back = read_trajectory(path)
    np.testing.assert_array_equal(back.views, views)
    np.testing.assert_array_equal(back.data, viewed.data)
    assert recordings.read_summary(path, "trajectory").views == 3
    with pytest.raises(recordings.RecordingError, match=r"feature views must have shape \(V >= 1, 7, 1280\)"):
        Trajectory.from_demonstration(demonstration_factory(7), traj.features, traj.extractor, views=views[:, :6])
    with pytest.raises(recordings.RecordingError, match="feature views need a feature block"):
        Trajectory.from_demonstration(demonstration_factory(7), views=views)
    writer = TrajectoryWriter(tmp_path / "w.mcap", viewed.episode, 1288, viewed.extractor, views=3)
    with pytest.raises(recordings.RecordingError, match="2 feature views for a file of 3 per step"), writer as w:
        w.write_steps(viewed.timestamps_ns, viewed.data, views=views[:2])
    assert not (tmp_path / "w.mcap").exists()  # a failed writer leaves nothing


def test_trajectory_blocks_view_the_right_columns():
    demo = demonstration_factory(steps=5, frames=False)
    feats = np.arange(5 * 1280, dtype=np.float32).reshape(5, 1280)
    traj = Trajectory.from_demonstration(demo, feats, {"architecture": "x"})
    np.testing.assert_array_equal(traj.features, feats)
    np.testing.assert_allclose(traj.pose, demo.pose.astype(np.float32))
    np.testing.assert_allclose(traj.gripper, demo.gripper.astype(np.float32))
    np.testing.assert_array_equal(traj.block("pose_xyz"), traj.data[:, 1280:1283])
    np.testing.assert_array_equal(traj.data[:, 1287], traj.gripper)


def test_streaming_writers_and_readers(tmp_path):
    demo = demonstration_factory(steps=6)
    with DemonstrationWriter(tmp_path / "d.mcap", demo.episode, demo.attachments) as w:
        for i in range(demo.n_steps):
            w.write_step(demo.timestamps_ns[i], demo.pose[i], demo.gripper[i], demo.frames[i])
    with DemonstrationReader(tmp_path / "d.mcap") as r:
        assert r.episode == demo.episode and r.n_steps == 6 and r.has_frames
        assert_same_demo(r.read(), demo)

    traj = trajectory_factory(steps=7)
    with TrajectoryWriter(tmp_path / "t.mcap", traj.episode, 1288, traj.extractor) as w:
        w.write_steps(traj.timestamps_ns[:3], traj.data[:3])
        for i in range(3, 7):
            w.write_step(traj.timestamps_ns[i], traj.data[i])
    with TrajectoryReader(tmp_path / "t.mcap") as r:
        assert r.width == 1288 and r.blocks == dict(BLOCKS_FULL) and r.extractor == traj.extractor and r.n_steps == 7
        np.testing.assert_array_equal(r.read().data, traj.data)


def test_failed_writer_leaves_nothing(tmp_path):
    demo = demonstration_factory(steps=3, frames=False)
    with pytest.raises(RuntimeError), DemonstrationWriter(tmp_path / "d.mcap", demo.episode) as w:
        w.write_step(0, demo.pose[0], 1.0)
        raise RuntimeError("recorder crashed")
    assert list(tmp_path.iterdir()) == []


def test_existing_output_is_kept_if_writing_fails(tmp_path):
    path = write_trajectory(tmp_path / "t.mcap", trajectory_factory(steps=4, features=False))
    before = path.read_bytes()
    with pytest.raises(recordings.RecordingError), TrajectoryWriter(path, trajectory_factory().episode, 8) as w:
        w.write_step(5, np.zeros(8, np.float32))  # zero quaternion: rejected
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.mcap"]


finite32 = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False, width=32)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    steps=st.integers(1, 40),
    features=st.booleans(),
    seed=st.integers(0, 2**32 - 1),
    start=st.integers(0, 2**62),
    gaps=st.lists(st.integers(1, 10**10), min_size=39, max_size=39),
    extreme=finite32,
)
def test_trajectory_round_trip_property(tmp_path, steps, features, seed, start, gaps, extreme):
    rng = np.random.default_rng(seed)
    width = 1288 if features else 8
    data = rng.normal(scale=1e3, size=(steps, width)).astype(np.float32)
    data[rng.integers(steps), rng.integers(width)] = extreme
    data[:, width - 5 : width - 1] = random_pose(steps, rng)[:, 3:]  # non-zero quaternion
    ts = start + np.concatenate([[0], np.cumsum(gaps[: steps - 1])]).astype(np.int64)
    traj = Trajectory(
        episode=Episode("prop", fps=rng.uniform(0.1, 1000)),
        timestamps_ns=ts,
        data=data,
        extractor={"architecture": "x"} if features else {},
    )
    back = read_trajectory(write_trajectory(tmp_path / "p.mcap", traj))
    np.testing.assert_array_equal(back.data, data)
    np.testing.assert_array_equal(back.timestamps_ns, ts)
    assert back.episode == traj.episode


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(
    pose_xyz=hnp.arrays(np.float64, st.tuples(st.integers(1, 30), st.just(3)), elements=st.floats(-1e9, 1e9)),
    seed=st.integers(0, 2**32 - 1),
    task=st.text(max_size=20),
)
def test_demonstration_round_trip_property(tmp_path, pose_xyz, seed, task):
    rng = np.random.default_rng(seed)
    steps = pose_xyz.shape[0]
    demo = recordings.Demonstration(
        episode=Episode("prop-demo", fps=30.0, task=task),
        timestamps_ns=np.sort(rng.choice(10**15, size=steps, replace=False)).astype(np.int64),
        pose=np.concatenate([pose_xyz, random_pose(steps, rng)[:, 3:]], axis=1),
        gripper=rng.normal(size=steps),
    )
    assert_same_demo(demo, read_demonstration(write_demonstration(tmp_path / "p.mcap", demo)))


def test_feature_vector_bytes_decode_with_the_protobuf_runtime():
    """Any protobuf-aware MCAP tool builds the class from the schema in the file: check it decodes ours."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    from cnep.recordings.schemas import encode_vector, feature_vector_schema, vector_payload

    pool = descriptor_pool.DescriptorPool()
    for fd in descriptor_pb2.FileDescriptorSet.FromString(feature_vector_schema()).file:
        pool.Add(fd)
    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName("cnep.FeatureVector"))
    row = np.random.default_rng(0).normal(size=1288).astype(np.float32)
    t = 1_700_000_000_123_456_789
    msg = cls.FromString(encode_vector(t, row))
    assert (msg.timestamp.seconds, msg.timestamp.nanos) == (1_700_000_000, 123_456_789)
    np.testing.assert_array_equal(np.array(msg.data, dtype=np.float32), row)
    # and our decoder reads what the protobuf runtime writes (packed and unpacked encodings)
    np.testing.assert_array_equal(np.frombuffer(vector_payload(msg.SerializeToString()), "<f4"), row)
    unpacked = b"".join(b"\x15" + np.float32(v).tobytes() for v in row[:3])  # field 2, wire type 5
    np.testing.assert_array_equal(np.frombuffer(vector_payload(unpacked), "<f4"), row[:3])


def test_recordings_never_imports_torch_pipeline_or_opencv_at_import():
    import subprocess
    import sys

    code = (
        "import sys, cnep.recordings, cnep.recordings.repair, cnep.recordings.inspection, cnep.recordings.mcap_source, "
        "cnep.recordings.adapters; "
        "print(','.join(m for m in ('torch', 'cnep.pipeline', 'cv2', 'cnep.perception', 'cnep.models') "
        "if m in sys.modules))"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == ""


@pytest.mark.parametrize("compression", ["", "lz4", "zstd"])
def test_reader_accepts_any_chunk_compression(tmp_path, compression):
    from cnep.recordings.container import new_writer

    traj = trajectory_factory(steps=9, features=False)
    contents = read_mcap(write_trajectory(tmp_path / "t.mcap", traj))
    with open(tmp_path / "c.mcap", "wb") as f:
        w = new_writer(f, compression)
        for name, data in contents.metadata.items():
            w.add_metadata(name, data)
        sid = {k: w.register_schema(s.name, s.encoding, s.data) for k, s in contents.schemas.items()}
        cid = {
            k: w.register_channel(c.topic, c.message_encoding, sid[c.schema_id], c.metadata)
            for k, c in contents.channels.items()
        }
        for m in contents.messages:
            w.add_message(cid[m.channel_id], m.log_time, m.data, m.publish_time)
        w.finish()
    back = read_trajectory(tmp_path / "c.mcap")
    np.testing.assert_array_equal(back.data, traj.data)
