"""Protobuf schemas of the recording topics and the encoding of one message per step.

Foxglove's well-known schemas (foxglove-schemas-protobuf) are used where one exists, so Foxglove and
Rerun open the files without our code. The trajectory vector is a small custom message built at run
time (no protoc needed):

    syntax = "proto3"; package cnep;
    message FeatureVector { google.protobuf.Timestamp timestamp = 1; repeated float data = 2; }

Its packed floats are written and read with numpy directly (the protobuf runtime is many times slower).
"""

from __future__ import annotations

from functools import cache, lru_cache
from typing import Any

import numpy as np
from foxglove_schemas_protobuf.CompressedImage_pb2 import CompressedImage
from foxglove_schemas_protobuf.Event_pb2 import Event as EventMsg
from foxglove_schemas_protobuf.JointState_pb2 import JointState
from foxglove_schemas_protobuf.JointStates_pb2 import JointStates
from foxglove_schemas_protobuf.KeyValuePair_pb2 import KeyValuePair
from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
from google.protobuf import descriptor_pb2, timestamp_pb2
from mcap_protobuf.schema import build_file_descriptor_set

from cnep.recordings.constants import FRAME_ID_BASE, FRAME_ID_CAMERA, GRIPPER_JOINT, IMAGE_FORMAT, SCHEMA_TRAJECTORY
from cnep.recordings.records import Event

NS_PER_S = 1_000_000_000


@cache
def schema_data(message_class: Any) -> bytes:
    """Serialized FileDescriptorSet of a generated protobuf message class (MCAP schema data)."""
    return build_file_descriptor_set(message_class).SerializeToString()


@lru_cache(maxsize=1)
def feature_vector_schema() -> bytes:
    """Serialized FileDescriptorSet of `cnep.FeatureVector` (with its Timestamp dependency)."""
    fd = descriptor_pb2.FileDescriptorProto(
        name="cnep/FeatureVector.proto",
        package="cnep",
        syntax="proto3",
        dependency=[timestamp_pb2.DESCRIPTOR.name],
    )
    msg = fd.message_type.add(name=SCHEMA_TRAJECTORY.split(".")[-1])
    F = descriptor_pb2.FieldDescriptorProto
    msg.field.add(
        name="timestamp", number=1, type=F.TYPE_MESSAGE, label=F.LABEL_OPTIONAL, type_name=".google.protobuf.Timestamp"
    )
    msg.field.add(name="data", number=2, type=F.TYPE_FLOAT, label=F.LABEL_REPEATED)  # packed (proto3 default)
    fds = descriptor_pb2.FileDescriptorSet()
    timestamp_pb2.DESCRIPTOR.CopyToProto(fds.file.add())
    fds.file.append(fd)
    return fds.SerializeToString()


# --- protobuf wire format helpers for FeatureVector -------------------------------------------------


def _varint(value: int) -> bytes:
    out = bytearray()
    while True:
        byte = value & 0x7F
        value >>= 7
        if value:
            out.append(byte | 0x80)
        else:
            out.append(byte)
            return bytes(out)


def _read_varint(buf: bytes, pos: int) -> tuple[int, int]:
    result = shift = 0
    while True:
        byte = buf[pos]
        pos += 1
        result |= (byte & 0x7F) << shift
        if not byte & 0x80:
            return result, pos
        shift += 7
        if shift > 63:
            raise ValueError("varint longer than 10 bytes")


def _timestamp_bytes(t_ns: int) -> bytes:
    sec, nsec = divmod(int(t_ns), NS_PER_S)
    body = (b"\x08" + _varint(sec) if sec else b"") + (b"\x10" + _varint(nsec) if nsec else b"")
    return b"\x0a" + _varint(len(body)) + body


def encode_vector(t_ns: int, row: np.ndarray) -> bytes:
    """FeatureVector bytes of one step: timestamp `t_ns` and `row` (D,) as packed little-endian float32."""
    payload = np.ascontiguousarray(row, dtype="<f4").tobytes()
    return _timestamp_bytes(t_ns) + b"\x12" + _varint(len(payload)) + payload


def vector_payload(buf: bytes) -> bytes:
    """The packed float32 bytes of field `data` in FeatureVector bytes `buf` (any field order).

    Also accepts the unpacked encoding (one fixed32 per value) that other writers may produce.
    Raises ValueError on malformed input.
    """
    # Fast path: what `encode_vector` writes (timestamp, then one packed field running to the end).
    if len(buf) > 3 and buf[0] == 0x0A and buf[1] < 0x80:
        pos = 2 + buf[1]
        if pos < len(buf) and buf[pos] == 0x12:
            length, start = _read_varint(buf, pos + 1)
            if start + length == len(buf) and length % 4 == 0:
                return buf[start:]
    parts: list[bytes] = []
    pos, end = 0, len(buf)
    while pos < end:
        key, pos = _read_varint(buf, pos)
        field_no, wire = key >> 3, key & 7
        if wire == 2:
            length, pos = _read_varint(buf, pos)
            if pos + length > end:
                raise ValueError("field runs past the end of the message")
            if field_no == 2:
                if length % 4:
                    raise ValueError(f"packed float field of {length} bytes is not a multiple of 4")
                parts.append(buf[pos : pos + length])
            pos += length
        elif wire == 5:
            if field_no == 2:
                parts.append(buf[pos : pos + 4])
            pos += 4
        elif wire == 0:
            _, pos = _read_varint(buf, pos)
        elif wire == 1:
            pos += 8
        else:
            raise ValueError(f"unsupported protobuf wire type {wire}")
    if pos != end:
        raise ValueError("message ends inside a field")
    return parts[0] if len(parts) == 1 else b"".join(parts)


# --- Foxglove messages ------------------------------------------------------------------------------


def _timestamp(t_ns: int) -> timestamp_pb2.Timestamp:
    sec, nsec = divmod(int(t_ns), NS_PER_S)
    return timestamp_pb2.Timestamp(seconds=sec, nanos=nsec)


def _ns(ts: timestamp_pb2.Timestamp) -> int:
    return ts.seconds * NS_PER_S + ts.nanos


def encode_pose(t_ns: int, pose: np.ndarray) -> bytes:
    """foxglove.PoseInFrame bytes of pose (7,) = xyz in m + quaternion xyzw, in frame `base`."""
    msg = PoseInFrame(timestamp=_timestamp(t_ns), frame_id=FRAME_ID_BASE)
    p = [float(v) for v in pose]
    msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = p[0], p[1], p[2]
    o = msg.pose.orientation
    o.x, o.y, o.z, o.w = p[3], p[4], p[5], p[6]
    return msg.SerializeToString()


def decode_pose(buf: bytes) -> list[float]:
    """[x, y, z, qx, qy, qz, qw] from foxglove.PoseInFrame bytes."""
    pose = PoseInFrame.FromString(buf).pose
    p, o = pose.position, pose.orientation
    return [p.x, p.y, p.z, o.x, o.y, o.z, o.w]


def encode_gripper(t_ns: int, value: float) -> bytes:
    """foxglove.JointStates bytes with one joint named `gripper` at position `value`."""
    msg = JointStates(timestamp=_timestamp(t_ns), joints=[JointState(name=GRIPPER_JOINT, position=float(value))])
    return msg.SerializeToString()


def decode_gripper(buf: bytes, joint: str = GRIPPER_JOINT) -> float:
    """Position of joint `joint` in foxglove.JointStates bytes; KeyError if absent."""
    for j in JointStates.FromString(buf).joints:
        if j.name == joint:
            return j.position
    raise KeyError(joint)


def encode_image(t_ns: int, jpeg: bytes) -> bytes:
    """foxglove.CompressedImage bytes of one JPEG frame in frame `camera`."""
    return CompressedImage(
        timestamp=_timestamp(t_ns), frame_id=FRAME_ID_CAMERA, data=jpeg, format=IMAGE_FORMAT
    ).SerializeToString()


def decode_image(buf: bytes) -> tuple[bytes, str]:
    """(image bytes, format) from foxglove.CompressedImage bytes."""
    msg = CompressedImage.FromString(buf)
    return msg.data, msg.format


def encode_event(event: Event) -> bytes:
    """foxglove.Event bytes: start/end time and key/value metadata."""
    msg = EventMsg(
        start_time=_timestamp(event.timestamp_ns),
        end_time=_timestamp(event.timestamp_ns + event.duration_ns),
        metadata=[KeyValuePair(key=k, value=v) for k, v in event.metadata.items()],
    )
    return msg.SerializeToString()


def decode_event(buf: bytes) -> Event:
    msg = EventMsg.FromString(buf)
    start = _ns(msg.start_time)
    return Event(
        timestamp_ns=start, duration_ns=_ns(msg.end_time) - start, metadata={kv.key: kv.value for kv in msg.metadata}
    )


# Message classes of the well-known schemas by schema name (for registering them in a writer).
FOXGLOVE_CLASSES = {cls.DESCRIPTOR.full_name: cls for cls in (CompressedImage, PoseInFrame, JointStates, EventMsg)}
