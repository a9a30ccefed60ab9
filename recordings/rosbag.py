"""Demonstrations from ROS bags through `rosbags` (pure Python, no ROS install): a ROS 1 `.bag` file, or a ROS 2
bag folder (`metadata.yaml` + SQLite3 `.db3` or `.mcap` storage).

The topics and their roles are those of a robot's MCAP (`recordings.mcap_source.McapTopics`, the same
`--image-topic --pose-topic --gripper-topic --gripper-joint` options) and so are the message types
(ROS 1 types are read under their ROS 2 names, e.g. `sensor_msgs/Image` as `sensor_msgs/msg/Image`):
`sensor_msgs/msg/Image` (rgb8, bgr8, mono8) or `CompressedImage`, `geometry_msgs/msg/PoseStamped` or
`TransformStamped` (or `tf2_msgs/msg/TFMessage`, e.g. `/tf`, for the transform whose child frame is
`pose_frame`), `sensor_msgs/msg/JointState` (the gripper joint by name). Each message's header stamp
is its time (the bag's receive time if the stamp is zero), and the time alignment is that of
`recordings.mcap_source.demonstration_from_series`.

Needs the optional extra `ros` (rosbags), imported lazily.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from cnep.recordings.errors import RecordingError
from cnep.recordings.mcap_source import (
    GRIPPER_EXTRACTORS,
    IMAGE_EXTRACTORS,
    POSE_EXTRACTORS,
    Extractor,
    McapTopics,
    Series,
    demonstration_from_series,
    ros_stamp,
    sorted_series,
    transform_pose,
)
from cnep.recordings.records import Demonstration

TF_TYPE = "tf2_msgs/msg/TFMessage"
INSTALL_HINT = "pip install 'cnep-pipeline[ros]'"


def is_ros2_bag(path: str | os.PathLike) -> bool:
    """True for a ROS 2 bag folder (it holds `metadata.yaml`)."""
    return (Path(path) / "metadata.yaml").is_file()


def _series(
    reader: Any, source: Path, topic: str, extractors: dict[str, Extractor], flag: str, topics: McapTopics
) -> Series:
    connections = [c for c in reader.connections if c.topic == topic]
    if not connections:
        raise RecordingError(f"{source}: no topic {topic!r} (topics: {sorted(reader.topics)}); choose one with {flag}")
    msgtype = connections[0].msgtype
    where = f"{source} {topic}"
    decoded: list[tuple[int, Any]] = []
    if msgtype == TF_TYPE and extractors is POSE_EXTRACTORS:
        if not topics.pose_frame:
            raise RecordingError(f"{where}: a tf topic holds many frames; name the one to use with --pose-frame")
        for conn, t, raw in reader.messages(connections=connections):
            for tf in reader.deserialize(raw, conn.msgtype).transforms:
                if tf.child_frame_id == topics.pose_frame:
                    decoded.append((ros_stamp(tf, t), transform_pose(tf.transform)))
        if not decoded:
            raise RecordingError(f"{where}: no transform with child frame {topics.pose_frame!r}; check --pose-frame")
        return sorted_series(decoded, where)
    if msgtype not in extractors:
        supported = sorted(extractors) + ([TF_TYPE] if extractors is POSE_EXTRACTORS else [])
        raise RecordingError(f"{where}: message type {msgtype!r} is not supported here (supported: {supported})")
    extract = extractors[msgtype]
    for conn, t, raw in reader.messages(connections=connections):
        decoded.append(extract(reader.deserialize(raw, conn.msgtype), t, where, topics))
    return sorted_series(decoded, where)


def demonstration_from_rosbag(
    path: str | os.PathLike, episode_id: str, topics: McapTopics = McapTopics(), task: str = ""
) -> Demonstration:
    """Read a ROS 1 `.bag` file or a ROS 2 bag folder into one demonstration."""
    try:
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
    except ImportError:
        raise RecordingError(f"{path}: reading ROS bags needs rosbags: {INSTALL_HINT}") from None
    source = Path(path)
    try:
        # ROS 2 bags may omit message definitions; the Humble type store supplies the standard ones.
        with AnyReader([source], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as reader:
            pose = _series(reader, source, topics.pose, POSE_EXTRACTORS, "--pose-topic", topics)
            gripper = (
                _series(reader, source, topics.gripper, GRIPPER_EXTRACTORS, "--gripper-topic", topics)
                if topics.gripper
                else None
            )
            image = (
                _series(reader, source, topics.image, IMAGE_EXTRACTORS, "--image-topic", topics)
                if topics.image
                else None
            )
    except RecordingError:
        raise
    except Exception as exc:  # rosbags raises its own error types per storage format (and struct errors on bad data)
        raise RecordingError(f"{source}: cannot read as a ROS bag ({type(exc).__name__}: {exc})") from None
    return demonstration_from_series(str(source), episode_id, topics, task, pose, gripper, image)
