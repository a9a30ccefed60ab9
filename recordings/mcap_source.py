"""Build a `Demonstration` from a robot's MCAP recording: image, pose and gripper topics.

Supported schemas:

| role | Foxglove (protobuf) | ROS 2 (cdr, needs `mcap-ros2-support`) |
|---|---|---|
| image | `foxglove.CompressedImage`, `foxglove.RawImage` | `sensor_msgs/msg/CompressedImage`, `sensor_msgs/msg/Image` |
| pose | `foxglove.PoseInFrame` | `geometry_msgs/msg/PoseStamped`, `geometry_msgs/msg/TransformStamped` |
| gripper | `foxglove.JointStates` | `sensor_msgs/msg/JointState` |

JPEG images are kept as they are; other compressed formats and raw images (rgb8, bgr8, mono8) are
encoded as JPEG. Each message's own timestamp is used (its log time when the timestamp is unset).
With an image topic, pose and gripper are interpolated at the frame times (xyz and gripper
linearly, quaternion by slerp); without one, steps are the pose messages.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.JointStates_pb2 import JointStates
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage

from cnep.recordings.adapters import median_rate, motion_at
from cnep.recordings.container import McapContents, read_mcap
from cnep.recordings.errors import RecordingError
from cnep.recordings.media import as_jpeg, encode_raw_image
from cnep.recordings.readers import in_file
from cnep.recordings.records import Demonstration, Episode
from cnep.recordings.validation import unit_quaternions

log = logging.getLogger(__name__)

NS_PER_S = 1_000_000_000
PROTOBUF_CLASSES = {c.DESCRIPTOR.full_name: c for c in (CompressedImage, RawImage, PoseInFrame, JointStates)}


@dataclass(frozen=True)
class McapTopics:
    """Topic names to read; `image=""` for a motion-only recording, `gripper=""` for none (0.0).

    Also used for ROS bags (recordings.rosbag), where the pose topic may be tf with `pose_frame` named.
    """

    image: str = "/camera/rgb"
    pose: str = "/ee/pose"
    gripper: str = "/gripper"
    gripper_joint: str = "gripper"
    pose_frame: str = ""  # ROS bags: the child frame to take from a tf2_msgs/TFMessage pose topic


# --- timestamps and images shared by both schema families -----------------------------------------


def _foxglove_stamp(msg: Any, log_time: int) -> int:
    ns = msg.timestamp.seconds * NS_PER_S + msg.timestamp.nanos
    return ns if ns > 0 else log_time


def ros_stamp(msg: Any, log_time: int) -> int:
    ns = msg.header.stamp.sec * NS_PER_S + msg.header.stamp.nanosec
    return ns if ns > 0 else log_time


def _jpeg_of_compressed(data: bytes, fmt: str, where: str) -> bytes:
    return as_jpeg(data, f"{where} ({fmt!r} image)")


_RAW_CHANNELS = {"rgb8": 3, "bgr8": 3, "mono8": 1}


def _jpeg_of_raw(width: int, height: int, encoding: str, step: int, data: bytes, where: str) -> bytes:
    if encoding not in _RAW_CHANNELS:
        raise RecordingError(f"{where}: raw image encoding {encoding!r} is not one of {sorted(_RAW_CHANNELS)}")
    ch = _RAW_CHANNELS[encoding]
    step = step or width * ch
    rows = np.frombuffer(bytes(data), np.uint8)[: step * height].reshape(height, step)  # (H, step)
    image = rows[:, : width * ch].reshape(height, width, ch)  # (H, W, C)
    if encoding == "rgb8":
        image = image[:, :, ::-1]  # OpenCV encodes BGR
    return encode_raw_image(np.ascontiguousarray(image), where)


def _pose_of(pose: Any) -> list[float]:
    p, o = pose.position, pose.orientation  # same field names in Foxglove and ROS 2
    return [p.x, p.y, p.z, o.x, o.y, o.z, o.w]


def transform_pose(transform: Any) -> list[float]:
    p, o = transform.translation, transform.rotation
    return [p.x, p.y, p.z, o.x, o.y, o.z, o.w]


def _joint_position(names: list[str], positions: list[float], joint: str, where: str) -> float:
    if joint not in names:
        raise RecordingError(f"{where}: a message has no joint {joint!r} (joints: {list(names)}); set --gripper-joint")
    return float(positions[list(names).index(joint)])


# Extractors: (decoded message, log time, where, options) -> (timestamp ns, value), by schema name.
Extractor = Callable[[Any, int, str, McapTopics], tuple[int, Any]]
IMAGE_EXTRACTORS: dict[str, Extractor] = {
    "foxglove.CompressedImage": lambda m, t, w, o: (_foxglove_stamp(m, t), _jpeg_of_compressed(m.data, m.format, w)),
    "foxglove.RawImage": lambda m, t, w, o: (
        _foxglove_stamp(m, t),
        _jpeg_of_raw(m.width, m.height, m.encoding, m.step, m.data, w),
    ),
    "sensor_msgs/msg/CompressedImage": lambda m, t, w, o: (ros_stamp(m, t), _jpeg_of_compressed(m.data, m.format, w)),
    "sensor_msgs/msg/Image": lambda m, t, w, o: (
        ros_stamp(m, t),
        _jpeg_of_raw(m.width, m.height, m.encoding, m.step, m.data, w),
    ),
}
POSE_EXTRACTORS: dict[str, Extractor] = {
    "foxglove.PoseInFrame": lambda m, t, w, o: (_foxglove_stamp(m, t), _pose_of(m.pose)),
    "geometry_msgs/msg/PoseStamped": lambda m, t, w, o: (ros_stamp(m, t), _pose_of(m.pose)),
    "geometry_msgs/msg/TransformStamped": lambda m, t, w, o: (ros_stamp(m, t), transform_pose(m.transform)),
}
GRIPPER_EXTRACTORS: dict[str, Extractor] = {
    "foxglove.JointStates": lambda m, t, w, o: (
        _foxglove_stamp(m, t),
        _joint_position([j.name for j in m.joints], [j.position for j in m.joints], o.gripper_joint, w),
    ),
    "sensor_msgs/msg/JointState": lambda m, t, w, o: (
        ros_stamp(m, t),
        _joint_position(m.name, m.position, o.gripper_joint, w),
    ),
}


def _decoder(contents: McapContents, topic: str) -> Callable[[bytes], Any]:
    """Function bytes -> message object for the channel of `topic` (protobuf or ROS 2 cdr)."""
    ch = contents.require_channel(topic)
    schema = contents.schemas.get(ch.schema_id)
    if ch.message_encoding == "protobuf" and schema is not None and schema.name in PROTOBUF_CLASSES:
        return PROTOBUF_CLASSES[schema.name].FromString
    if ch.message_encoding == "cdr" and schema is not None:
        try:
            from mcap_ros2.decoder import DecoderFactory
        except ImportError:
            raise RecordingError(
                f"{contents.path}: {topic!r} is ROS 2 data; install mcap-ros2-support to read it"
            ) from None
        decode = DecoderFactory().decoder_for(ch.message_encoding, schema)
        if decode is not None:
            return decode
    name = schema.name if schema is not None else "no schema"
    foxglove = ", ".join(sorted(PROTOBUF_CLASSES))
    raise RecordingError(
        f"{contents.path}: {topic!r} holds {ch.message_encoding or 'unnamed'}-encoded messages of schema {name!r}, "
        f"which cnep does not read: it reads protobuf-encoded Foxglove schemas ({foxglove}) and cdr-encoded ROS 2 "
        f"messages; record the topic in one of those, or choose another topic with the --*-topic options"
    )


def sorted_series(decoded: list[tuple[int, Any]], where: str) -> tuple[np.ndarray, list]:
    """(times (N,) int64 ascending, values) of (time, value) pairs; a repeated time keeps its first message."""
    decoded = sorted(decoded, key=lambda tv: tv[0])
    times = np.array([t for t, _ in decoded], dtype=np.int64)
    first = np.concatenate([[True], np.diff(times) > 0])
    if not first.all():
        log.warning("%s: %d messages repeat an earlier timestamp and are dropped", where, int((~first).sum()))
    if first.sum() < 2:
        raise RecordingError(f"{where}: fewer than 2 messages with distinct timestamps")
    return times[first], [v for (_, v), k in zip(decoded, first) if k]


def _series(
    contents: McapContents, topic: str, extractors: dict[str, Extractor], flag: str, topics: McapTopics
) -> tuple[np.ndarray, list]:
    """(times (N,) int64 sorted, values) of `topic`; duplicate times keep their first message."""
    contents.require_channel(topic, hint=f"; choose one with {flag}")
    schema = contents.schema_name(topic)
    if schema not in extractors:
        raise RecordingError(f"{contents.path}: topic {topic!r} has schema {schema!r}; supported: {sorted(extractors)}")
    decode, extract, where = _decoder(contents, topic), extractors[schema], f"{contents.path} {topic}"
    return sorted_series(
        [extract(decode(m.data), m.log_time, where, topics) for m in contents.topic_messages(topic)], where
    )


Series = tuple[np.ndarray, list]  # (times (N,) int64 ascending, values)


def demonstration_from_series(
    source: str,
    episode_id: str,
    topics: McapTopics,
    task: str,
    pose_series: Series,
    gripper_series: Series | None,
    image_series: Series | None,
) -> Demonstration:
    """A demonstration from time series of poses (xyz + quaternion xyzw), gripper values and JPEG frames.

    With frames, the steps are the frames and pose/gripper are interpolated at their times (xyz and
    gripper linearly, the quaternion by slerp); without, the steps are the poses. `source` names the
    recording in errors.
    """
    pose_t, pose_v = pose_series
    pose = np.asarray(pose_v, dtype=np.float64)  # (N, 7)
    labels = [f"the pose on {topics.pose!r} at {t} ns" for t in pose_t.tolist()]
    pose[:, 3:], note = unit_quaternions(pose[:, 3:], source, labels)
    if gripper_series is not None:
        grip_t, gripper = gripper_series[0], np.asarray(gripper_series[1], dtype=np.float64)
    else:
        grip_t, gripper = pose_t, np.zeros(len(pose_t))
    extra = {"image_topic": topics.image, "pose_topic": topics.pose, "gripper_topic": topics.gripper}
    if note:
        extra["quaternions"] = note
    if image_series is not None:
        times, frames = image_series
        extra["interpolation"] = "pose xyz and gripper linear, quaternion slerp, at frame times"
    else:
        times, frames = pose_t, None
        extra["interpolation"] = "gripper linear at pose times"
    keep, pose_q, grip_q = motion_at(times, pose_t, pose, grip_t, gripper)
    if keep.sum() < 2:
        raise RecordingError(f"{source}: fewer than 2 steps fall inside the time span of both pose and gripper")
    if (~keep).any():
        log.info("%s: %d steps outside the pose/gripper time span are dropped", source, int((~keep).sum()))
    times = times[keep]
    return Demonstration(
        episode=Episode(episode_id, fps=median_rate(times), task=task, source=source, extra=extra),
        timestamps_ns=times,
        pose=pose_q,
        gripper=grip_q,
        frames=None if frames is None else [f for f, k in zip(frames, keep) if k],
    )


def demonstration_from_mcap(
    path: str | os.PathLike, episode_id: str, topics: McapTopics = McapTopics(), task: str = ""
) -> Demonstration:
    """Read a robot's MCAP recording (strict: a damaged file is refused; `cnep repair` it first)."""
    contents = read_mcap(path)
    with in_file(contents.path):
        pose = _series(contents, topics.pose, POSE_EXTRACTORS, "--pose-topic", topics)
        gripper = (
            _series(contents, topics.gripper, GRIPPER_EXTRACTORS, "--gripper-topic", topics) if topics.gripper else None
        )
        image = _series(contents, topics.image, IMAGE_EXTRACTORS, "--image-topic", topics) if topics.image else None
        return demonstration_from_series(str(contents.path), episode_id, topics, task, pose, gripper, image)
