"""ROS 1 and ROS 2 bags written with `rosbags`, with known values at known header stamps.

Poses (`geometry_msgs/PoseStamped` on /ee/pose, or tf) at 50 Hz and the gripper (`sensor_msgs/JointState`
on /gripper, joints finger and gripper) at 20 Hz sample `tests.recordings.sources.motion` over [0, 1] s after
T0; camera frames (10 Hz, `sensor_msgs/Image` rgb8 or `CompressedImage` jpeg) at FRAME_TIMES_S, a uniform
grey of level `frame_level(k)`. The last frame lies after the motion ends, so ingest drops it.
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from tests.recordings.sources import motion

T0_NS = 1_700_000_000_000_000_000
FRAME_TIMES_S = 0.05 + 0.1 * np.arange(11)  # 0.05 ... 1.05 s; the last is outside the motion's [0, 1] s
POSE_TIMES_S = np.arange(51) / 50.0
GRIPPER_TIMES_S = np.arange(21) / 20.0
SIZE = 16


def frame_level(k: int) -> int:
    return 20 + 20 * k


def _stamp(store, t_s: float):
    ns = T0_NS + round(t_s * 1e9)
    return store.types["builtin_interfaces/msg/Time"](sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def _header(store, t_s: float, frame: str, ros1: bool):
    Header = store.types["std_msgs/msg/Header"]
    if ros1:
        return Header(seq=0, stamp=_stamp(store, t_s), frame_id=frame)
    return Header(stamp=_stamp(store, t_s), frame_id=frame)


def _messages(store, ros1: bool, compressed: bool, tf: bool) -> list[tuple[str, str, float, object]]:
    """(topic, msgtype, time s, message) of the whole recording."""
    t = store.types
    out = []
    for k, ts in enumerate(FRAME_TIMES_S):
        image = np.full((SIZE, SIZE, 3), frame_level(k), np.uint8)
        header = _header(store, ts, "camera", ros1)
        if compressed:
            data = np.frombuffer(cv2.imencode(".jpg", image)[1].tobytes(), np.uint8)
            out.append(
                (
                    "/camera/rgb",
                    "sensor_msgs/msg/CompressedImage",
                    ts,
                    t["sensor_msgs/msg/CompressedImage"](header=header, format="jpeg", data=data),
                )
            )
        else:
            out.append(
                (
                    "/camera/rgb",
                    "sensor_msgs/msg/Image",
                    ts,
                    t["sensor_msgs/msg/Image"](
                        header=header,
                        height=SIZE,
                        width=SIZE,
                        encoding="rgb8",
                        is_bigendian=0,
                        step=SIZE * 3,
                        data=image.reshape(-1),
                    ),
                )
            )
    poses, _ = motion(POSE_TIMES_S)
    for ts, p in zip(POSE_TIMES_S, poses):
        if tf:
            transform = t["geometry_msgs/msg/Transform"](
                translation=t["geometry_msgs/msg/Vector3"](x=p[0], y=p[1], z=p[2]),
                rotation=t["geometry_msgs/msg/Quaternion"](x=p[3], y=p[4], z=p[5], w=p[6]),
            )
            other = t["geometry_msgs/msg/Transform"](
                translation=t["geometry_msgs/msg/Vector3"](x=9.0, y=9.0, z=9.0),
                rotation=t["geometry_msgs/msg/Quaternion"](x=0.0, y=0.0, z=0.0, w=1.0),
            )
            stamped = [
                t["geometry_msgs/msg/TransformStamped"](
                    header=_header(store, ts, "base", ros1), child_frame_id=child, transform=tr
                )
                for child, tr in (("camera_link", other), ("tool0", transform))
            ]
            out.append(("/tf", "tf2_msgs/msg/TFMessage", ts, t["tf2_msgs/msg/TFMessage"](transforms=stamped)))
        else:
            pose = t["geometry_msgs/msg/Pose"](
                position=t["geometry_msgs/msg/Point"](x=p[0], y=p[1], z=p[2]),
                orientation=t["geometry_msgs/msg/Quaternion"](x=p[3], y=p[4], z=p[5], w=p[6]),
            )
            out.append(
                (
                    "/ee/pose",
                    "geometry_msgs/msg/PoseStamped",
                    ts,
                    t["geometry_msgs/msg/PoseStamped"](header=_header(store, ts, "base", ros1), pose=pose),
                )
            )
    _, grip = motion(GRIPPER_TIMES_S)
    for ts, g in zip(GRIPPER_TIMES_S, grip):
        out.append(
            (
                "/gripper",
                "sensor_msgs/msg/JointState",
                ts,
                t["sensor_msgs/msg/JointState"](
                    header=_header(store, ts, "", ros1),
                    name=["finger", "gripper"],
                    position=np.array([0.0, g]),
                    velocity=np.array([], np.float64),
                    effort=np.array([], np.float64),
                ),
            )
        )
    return sorted(out, key=lambda m: m[2])


def write_ros1_bag(path: Path, compressed: bool = False, tf: bool = False) -> Path:
    """A ROS 1 .bag file (received 2 ms after each header stamp)."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS1_NOETIC)
    with Writer(path) as writer:
        connections = {}
        for topic, msgtype, ts, msg in _messages(store, ros1=True, compressed=compressed, tf=tf):
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(connections[topic], T0_NS + round(ts * 1e9) + 2_000_000, store.serialize_ros1(msg, msgtype))
    return path


def write_ros2_bag(path: Path, storage: str = "sqlite3", compressed: bool = False, tf: bool = False) -> Path:
    """A ROS 2 bag folder with SQLite3 (`.db3`) or MCAP storage."""
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        connections = {}
        for topic, msgtype, ts, msg in _messages(store, ros1=False, compressed=compressed, tf=tf):
            if topic not in connections:
                connections[topic] = writer.add_connection(topic, msgtype, typestore=store)
            writer.write(connections[topic], T0_NS + round(ts * 1e9) + 2_000_000, store.serialize_cdr(msg, msgtype))
    return path
