"""Build a `Demonstration` from a robot's MCAP recording with Foxglove image, pose and gripper topics.

Supported schemas (protobuf): images `foxglove.CompressedImage` (JPEG kept as is, other formats
re-encoded) or `foxglove.RawImage` (rgb8, bgr8, mono8); pose `foxglove.PoseInFrame`; gripper
`foxglove.JointStates` (one joint picked by name). Each message's own timestamp is used (its log
time when the timestamp is unset). With an image topic, pose and gripper are interpolated at the
frame times (see `recordings.adapters`); without one, steps are the pose messages.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from typing import Callable

import numpy as np
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.JointStates_pb2 import JointStates
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from foxglove_schemas_protobuf.RawImage_pb2 import RawImage

from recordings.adapters import median_rate, motion_at
from recordings.container import McapContents, read_mcap
from recordings.errors import RecordingError
from recordings.media import encode_raw_image
from recordings.readers import in_file
from recordings.records import Demonstration, Episode
from recordings.validation import JPEG_MAGIC

log = logging.getLogger(__name__)

NS_PER_S = 1_000_000_000


@dataclass(frozen=True)
class McapTopics:
    """Topic names to read; `image=""` for a motion-only recording, `gripper=""` for none (0.0)."""

    image: str = "/camera/rgb"
    pose: str = "/ee/pose"
    gripper: str = "/gripper"
    gripper_joint: str = "gripper"


def _stamp(ts: object, log_time: int) -> int:
    ns = ts.seconds * NS_PER_S + ts.nanos  # type: ignore[attr-defined]
    return ns if ns > 0 else log_time


def _image_compressed(data: bytes, log_time: int, where: str) -> tuple[int, bytes]:
    msg = CompressedImage.FromString(data)
    if msg.data[:2] == JPEG_MAGIC:
        return _stamp(msg.timestamp, log_time), msg.data
    import cv2

    image = cv2.imdecode(np.frombuffer(msg.data, np.uint8), cv2.IMREAD_COLOR)
    if image is None:
        raise RecordingError(f"{where}: cannot decode a {msg.format!r} image")
    return _stamp(msg.timestamp, log_time), encode_raw_image(image, where)


_RAW_CHANNELS = {"rgb8": 3, "bgr8": 3, "mono8": 1}


def _image_raw(data: bytes, log_time: int, where: str) -> tuple[int, bytes]:
    msg = RawImage.FromString(data)
    if msg.encoding not in _RAW_CHANNELS:
        raise RecordingError(f"{where}: raw image encoding {msg.encoding!r} is not one of {sorted(_RAW_CHANNELS)}")
    ch = _RAW_CHANNELS[msg.encoding]
    step = msg.step or msg.width * ch
    rows = np.frombuffer(msg.data, np.uint8)[: step * msg.height].reshape(msg.height, step)  # (H, step)
    image = rows[:, : msg.width * ch].reshape(msg.height, msg.width, ch)  # (H, W, C)
    if msg.encoding == "rgb8":
        image = image[:, :, ::-1]  # OpenCV encodes BGR
    return _stamp(msg.timestamp, log_time), encode_raw_image(np.ascontiguousarray(image), where)


def _pose(data: bytes, log_time: int, where: str) -> tuple[int, list[float]]:
    msg = PoseInFrame.FromString(data)
    p, o = msg.pose.position, msg.pose.orientation
    return _stamp(msg.timestamp, log_time), [p.x, p.y, p.z, o.x, o.y, o.z, o.w]


def _joint(joint: str) -> Callable[[bytes, int, str], tuple[int, float]]:
    def decode(data: bytes, log_time: int, where: str) -> tuple[int, float]:
        msg = JointStates.FromString(data)
        for j in msg.joints:
            if j.name == joint:
                return _stamp(msg.timestamp, log_time), j.position
        raise RecordingError(f"{where}: a message has no joint {joint!r} (joints: {[j.name for j in msg.joints]}); set --gripper-joint")

    return decode


IMAGE_DECODERS = {"foxglove.CompressedImage": _image_compressed, "foxglove.RawImage": _image_raw}
POSE_DECODERS = {"foxglove.PoseInFrame": _pose}
GRIPPER_SCHEMAS = ("foxglove.JointStates",)


def _series(contents: McapContents, topic: str, decoders: dict[str, Callable], flag: str) -> tuple[np.ndarray, list]:
    """(times (N,) int64 sorted, values) of `topic`; duplicate times keep their first message."""
    if contents.channel_of_topic(topic) is None:
        have = sorted({c.topic for c in contents.channels.values()})
        raise RecordingError(f"{contents.path}: missing topic {topic!r} (topics in the file: {have}); choose one with {flag}")
    schema = contents.schema_name(topic)
    if schema not in decoders:
        raise RecordingError(f"{contents.path}: topic {topic!r} has schema {schema!r}; supported: {sorted(decoders)}")
    where = f"{contents.path} {topic}"
    decoded = [decoders[schema](m.data, m.log_time, where) for m in contents.topic_messages(topic)]
    decoded.sort(key=lambda tv: tv[0])
    times = np.array([t for t, _ in decoded], dtype=np.int64)
    first = np.concatenate([[True], np.diff(times) > 0])
    if not first.all():
        log.warning("%s: %d messages repeat an earlier timestamp and are dropped", where, int((~first).sum()))
    if first.sum() < 2:
        raise RecordingError(f"{where}: fewer than 2 messages with distinct timestamps")
    return times[first], [v for (_, v), k in zip(decoded, first) if k]


def demonstration_from_mcap(path: str | os.PathLike, episode_id: str, topics: McapTopics = McapTopics(), task: str = "") -> Demonstration:
    """Read a robot's MCAP recording (strict: a damaged file is refused; `cnep repair` it first)."""
    contents = read_mcap(path)
    with in_file(contents.path):
        pose_t, pose_v = _series(contents, topics.pose, POSE_DECODERS, "--pose-topic")
        pose = np.asarray(pose_v, dtype=np.float64)  # (N, 7)
        norms = np.linalg.norm(pose[:, 3:], axis=1)
        if (norms < 1e-6).any():
            raise RecordingError(f"{contents.path}: a pose on {topics.pose!r} has a zero quaternion")
        pose[:, 3:] /= norms[:, None]
        if topics.gripper:
            grip_t, grip_v = _series(contents, topics.gripper, dict.fromkeys(GRIPPER_SCHEMAS, _joint(topics.gripper_joint)), "--gripper-topic")
            gripper = np.asarray(grip_v, dtype=np.float64)
        else:
            grip_t, gripper = pose_t, np.zeros(len(pose_t))
        extra = {"image_topic": topics.image, "pose_topic": topics.pose, "gripper_topic": topics.gripper}
        if topics.image:
            times, frames = _series(contents, topics.image, IMAGE_DECODERS, "--image-topic")
            extra["interpolation"] = "pose xyz and gripper linear, quaternion slerp, at frame times"
        else:
            times, frames = pose_t, None
            extra["interpolation"] = "gripper linear at pose times"
        keep, pose_q, grip_q = motion_at(times, pose_t, pose, grip_t, gripper)
        if keep.sum() < 2:
            raise RecordingError(f"{contents.path}: fewer than 2 steps fall inside the time span of both pose and gripper")
        if (~keep).any():
            log.info("%s: %d steps outside the pose/gripper time span are dropped", contents.path, int((~keep).sum()))
        times = times[keep]
        return Demonstration(
            episode=Episode(episode_id, fps=median_rate(times), task=task, source=str(contents.path), extra=extra),
            timestamps_ns=times,
            pose=pose_q,
            gripper=grip_q,
            frames=None if frames is None else [f for f, k in zip(frames, keep) if k],
        )
