"""Synthetic raw recordings in the formats `cnep ingest` reads (written into a test's tmp_path)."""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

BAXTER_HEADER = (
    "Time,ROS secs,ROS nsecs,________p_x________,________p_y________,________p_z________,"
    "________q_x________,________q_y________,________q_z________,________q_w________,"
    "gripper_position,gripper_force,right_e0,right_e1,right_s0,right_s1,right_w0,right_w1,right_w2"
)


def z_quat(angle: np.ndarray) -> np.ndarray:
    """Quaternions xyzw (N, 4) of rotations by `angle` rad about z."""
    return np.stack([np.zeros_like(angle), np.zeros_like(angle), np.sin(angle / 2), np.cos(angle / 2)], axis=1)


def motion(t_s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The ground-truth movement at times t_s (s): pose (N, 7) (linear xyz, z rotation at 1 rad/s), gripper (N,)."""
    xyz = np.stack([0.7 + 0.1 * t_s, -0.5 + 0.2 * t_s, -0.1 + 0 * t_s], axis=1)
    return np.concatenate([xyz, z_quat(1.0 * t_s)], axis=1), 96.0 - 10.0 * t_s


def baxter_csv(path: Path, times_ms: np.ndarray) -> Path:
    """A CSV in the Baxter format (19 columns, padded headers, Time in ms) sampling `motion`."""
    pose, grip = motion(times_ms / 1000.0)
    rows = [BAXTER_HEADER]
    for t, p, g in zip(times_ms, pose, grip):
        values = [t, 1697207899, 333935758, *p, g, 0.0, *([0.1] * 7)]
        rows.append(",".join(repr(float(v)) if i else str(v) for i, v in enumerate(values)))
    path.write_text("\n".join(rows) + "\n")
    return path


def images(folder: Path, n: int, suffix: str = ".png", size: int = 24) -> list[Path]:
    """n numbered images frame_0..frame_{n-1} whose brightness encodes the index."""
    out = []
    for i in range(n):
        img = np.full((size, size, 3), (i * 20) % 256, np.uint8)
        path = folder / f"frame_{i}{suffix}"
        assert cv2.imwrite(str(path), img)
        out.append(path)
    return out


def video(path: Path, n: int, fps: float, size: int = 32) -> Path:
    """An MJPG AVI of n frames at `fps`."""
    writer = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), fps, (size, size))
    assert writer.isOpened()
    for i in range(n):
        writer.write(np.full((size, size, 3), (i * 20) % 256, np.uint8))
    writer.release()
    return path


def robot_mcap(path: Path, duration_s: float = 1.0, camera_hz: float = 10.0, pose_hz: float = 50.0, gripper_hz: float = 20.0) -> Path:
    """A robot's MCAP with Foxglove schemas on non-default topics: /robot/camera (RawImage rgb8),
    /robot/ee (PoseInFrame), /robot/joints (JointStates with joints `finger` and `gripper_joint`).
    Message timestamps follow `motion`; log times lag them by 3 ms (as a recorder's would)."""
    from foxglove_schemas_protobuf.JointState_pb2 import JointState
    from foxglove_schemas_protobuf.JointStates_pb2 import JointStates
    from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
    from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
    from google.protobuf.timestamp_pb2 import Timestamp
    from mcap_protobuf.writer import Writer

    t0 = 1_700_000_000_000_000_000
    lag = 3_000_000

    def stamp(t_ns: int) -> Timestamp:
        return Timestamp(seconds=t_ns // 10**9, nanos=t_ns % 10**9)

    events = []
    for i in range(int(duration_s * camera_hz) + 1):
        t = t0 + round(i * 1e9 / camera_hz)
        img = np.full((8, 8, 3), (i * 20) % 256, np.uint8)
        events.append((t, "/robot/camera", RawImage(timestamp=stamp(t), width=8, height=8, encoding="rgb8", step=24, data=img.tobytes())))
    for i in range(int(duration_s * pose_hz) + 1):
        t = t0 + round(i * 1e9 / pose_hz)
        p = motion(np.array([(t - t0) / 1e9]))[0][0]
        msg = PoseInFrame(timestamp=stamp(t), frame_id="base")
        msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = p[:3]
        msg.pose.orientation.x, msg.pose.orientation.y, msg.pose.orientation.z, msg.pose.orientation.w = p[3:]
        events.append((t, "/robot/ee", msg))
    for i in range(int(duration_s * gripper_hz) + 1):
        t = t0 + round(i * 1e9 / gripper_hz)
        g = motion(np.array([(t - t0) / 1e9]))[1][0]
        joints = [JointState(name="finger", position=-1.0), JointState(name="gripper_joint", position=g)]
        events.append((t, "/robot/joints", JointStates(timestamp=stamp(t), joints=joints)))
    with open(path, "wb") as f, Writer(f) as w:
        for t, topic, msg in sorted(events, key=lambda e: e[0]):
            w.write_message(topic, msg, log_time=t + lag, publish_time=t + lag)
    return path
