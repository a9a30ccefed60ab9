"""ROS 1 and ROS 2 bags in (through rosbags): frames at their header stamps, pose and gripper interpolated there."""

import cv2
import numpy as np
import pytest

pytest.importorskip("rosbags")

from cnep.pipeline.cli.main import main  # noqa: E402
from cnep.pipeline.ingest.stage import IngestConfig, ingest  # noqa: E402
from cnep.recordings import RecordingError, read_demonstration  # noqa: E402
from cnep.recordings.mcap_source import McapTopics  # noqa: E402
from cnep.recordings.rosbag import demonstration_from_rosbag  # noqa: E402
from tests.recordings.rosbag_sources import FRAME_TIMES_S, T0_NS, frame_level, write_ros1_bag, write_ros2_bag  # noqa: E402
from tests.recordings.sources import motion  # noqa: E402

BAGS = {
    "ros1": lambda d: write_ros1_bag(d / "run.bag"),
    "ros1-compressed": lambda d: write_ros1_bag(d / "run.bag", compressed=True),
    "ros2-sqlite3": lambda d: write_ros2_bag(d / "run"),
    "ros2-mcap-compressed": lambda d: write_ros2_bag(d / "run", storage="mcap", compressed=True),
}


@pytest.mark.parametrize("kind", sorted(BAGS))
def test_frames_keep_their_stamps_and_motion_is_interpolated_there(tmp_path, kind):
    (tmp_path / "in").mkdir()
    BAGS[kind](tmp_path / "in")
    done = ingest(IngestConfig(src=tmp_path / "in", out=tmp_path / "out", quiet=True))
    assert [d.output.relative_to(tmp_path / "out").as_posix() for d in done] == ["run.mcap"]  # storage files not twice
    demo = read_demonstration(done[0].output)
    kept = FRAME_TIMES_S[:-1]  # the last frame is after the motion ends: dropped, not extrapolated
    np.testing.assert_array_equal(demo.timestamps_ns, T0_NS + np.round(kept * 1e9).astype(np.int64))
    pose, gripper = motion(kept)
    np.testing.assert_allclose(demo.pose, pose, atol=1e-12)
    np.testing.assert_allclose(demo.gripper, gripper, atol=1e-12)
    levels = [cv2.imdecode(np.frombuffer(f, np.uint8), cv2.IMREAD_COLOR).mean() for f in demo.frames]
    np.testing.assert_allclose(levels, [frame_level(k) for k in range(len(kept))], atol=2)


def test_tf_pose_of_a_named_frame(tmp_path):
    bag = write_ros2_bag(tmp_path / "tf")
    bag_tf = write_ros2_bag(tmp_path / "tf2", tf=True)
    with pytest.raises(RecordingError, match="name the one to use with --pose-frame"):
        demonstration_from_rosbag(bag_tf, "x", McapTopics(pose="/tf"))
    with pytest.raises(RecordingError, match="no transform with child frame 'wrist'"):
        demonstration_from_rosbag(bag_tf, "x", McapTopics(pose="/tf", pose_frame="wrist"))
    from_tf = demonstration_from_rosbag(bag_tf, "x", McapTopics(pose="/tf", pose_frame="tool0"))
    from_pose = demonstration_from_rosbag(bag, "x")
    np.testing.assert_allclose(from_tf.pose, from_pose.pose, atol=1e-12)


def test_motion_only_bag_steps_are_the_poses(tmp_path):
    demo = demonstration_from_rosbag(write_ros1_bag(tmp_path / "a.bag"), "a", McapTopics(image=""))
    assert demo.frames is None and demo.n_steps == 51


@pytest.mark.parametrize(
    "args, expected",
    [
        (
            ["--pose-topic", "/pose"],
            "no topic '/pose' (topics: ['/camera/rgb', '/ee/pose', '/gripper']); choose one with --pose-topic",
        ),
        (["--gripper-joint", "hand"], "no joint 'hand' (joints: ['finger', 'gripper']); set --gripper-joint"),
        (["--image-topic", "/ee/pose"], "message type 'geometry_msgs/msg/PoseStamped' is not supported here"),
    ],
)
def test_bad_topic_choices_are_one_line_errors_and_write_nothing(tmp_path, capsys, args, expected):
    bag = write_ros1_bag(tmp_path / "a.bag")
    assert main(["-q", "ingest", str(bag), "--out", str(tmp_path / "out"), *args]) == 2
    err = capsys.readouterr().err.strip()
    assert expected in err and str(bag) in err and "\n" not in err
    assert not any((tmp_path / "out").glob("*.mcap"))


def test_a_damaged_bag_is_named(tmp_path, capsys):
    bag = write_ros1_bag(tmp_path / "a.bag")
    bag.write_bytes(bag.read_bytes()[:300])
    assert main(["-q", "ingest", str(bag), "--out", str(tmp_path / "out")]) == 2
    assert f"{bag}: cannot read as a ROS bag" in capsys.readouterr().err
