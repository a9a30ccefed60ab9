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


T0_NS = 1_700_000_000_000_000_000


def robot_samples(
    duration_s: float, camera_hz: float, pose_hz: float, gripper_hz: float
) -> list[tuple[int, str, object]]:
    """(time ns, role, value) of a robot's streams sampling `motion`, sorted by time.

    role "camera": an 8x8 RGB uint8 image whose brightness encodes the frame index;
    role "pose": (7,) pose; role "gripper": gripper value.
    """
    samples = []
    for role, hz in (("camera", camera_hz), ("pose", pose_hz), ("gripper", gripper_hz)):
        for i in range(int(duration_s * hz) + 1):
            t = T0_NS + round(i * 1e9 / hz)
            pose, grip = motion(np.array([(t - T0_NS) / 1e9]))
            value = {"camera": np.full((8, 8, 3), (i * 20) % 256, np.uint8), "pose": pose[0], "gripper": grip[0]}[role]
            samples.append((t, role, value))
    return sorted(samples, key=lambda s: s[0])


def robot_mcap(
    path: Path, duration_s: float = 1.0, camera_hz: float = 10.0, pose_hz: float = 50.0, gripper_hz: float = 20.0
) -> Path:
    """A robot's MCAP with Foxglove schemas on non-default topics: /robot/camera (RawImage rgb8),
    /robot/ee (PoseInFrame), /robot/joints (JointStates with joints `finger` and `gripper_joint`).
    Message timestamps follow `motion`; log times lag them by 3 ms (as a recorder's would)."""
    from foxglove_schemas_protobuf.JointState_pb2 import JointState
    from foxglove_schemas_protobuf.JointStates_pb2 import JointStates
    from foxglove_schemas_protobuf.PoseInFrame_pb2 import PoseInFrame
    from foxglove_schemas_protobuf.RawImage_pb2 import RawImage
    from google.protobuf.timestamp_pb2 import Timestamp
    from mcap_protobuf.writer import Writer

    def message(t: int, role: str, value):
        stamp = Timestamp(seconds=t // 10**9, nanos=t % 10**9)
        if role == "camera":
            return "/robot/camera", RawImage(
                timestamp=stamp, width=8, height=8, encoding="rgb8", step=24, data=value.tobytes()
            )
        if role == "pose":
            msg = PoseInFrame(timestamp=stamp, frame_id="base")
            msg.pose.position.x, msg.pose.position.y, msg.pose.position.z = value[:3]
            msg.pose.orientation.x, msg.pose.orientation.y, msg.pose.orientation.z, msg.pose.orientation.w = value[3:]
            return "/robot/ee", msg
        joints = [JointState(name="finger", position=-1.0), JointState(name="gripper_joint", position=value)]
        return "/robot/joints", JointStates(timestamp=stamp, joints=joints)

    with open(path, "wb") as f, Writer(f) as w:
        for t, role, value in robot_samples(duration_s, camera_hz, pose_hz, gripper_hz):
            topic, msg = message(t, role, value)
            w.write_message(topic, msg, log_time=t + 3_000_000, publish_time=t + 3_000_000)
    return path


SEPARATOR = "=" * 80
HEADER_DEFS = f"""{SEPARATOR}
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
{SEPARATOR}
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec"""
ROS2_MSGDEFS = {
    "sensor_msgs/msg/CompressedImage": f"std_msgs/Header header\nstring format\nuint8[] data\n{HEADER_DEFS}",
    "geometry_msgs/msg/PoseStamped": f"""std_msgs/Header header
geometry_msgs/Pose pose
{HEADER_DEFS}
{SEPARATOR}
MSG: geometry_msgs/Pose
Point position
Quaternion orientation
{SEPARATOR}
MSG: geometry_msgs/Point
float64 x
float64 y
float64 z
{SEPARATOR}
MSG: geometry_msgs/Quaternion
float64 x
float64 y
float64 z
float64 w""",
    "sensor_msgs/msg/JointState": "std_msgs/Header header\nstring[] name\nfloat64[] position\nfloat64[] velocity\n"
    f"float64[] effort\n{HEADER_DEFS}",
}


def jpeg_of(rgb: np.ndarray) -> bytes:
    """JPEG bytes (OpenCV defaults) of an RGB uint8 image."""
    ok, buf = cv2.imencode(".jpg", np.ascontiguousarray(rgb[:, :, ::-1]))
    assert ok
    return buf.tobytes()


def ros2_robot_mcap(
    path: Path, duration_s: float = 1.0, camera_hz: float = 10.0, pose_hz: float = 50.0, gripper_hz: float = 20.0
) -> Path:
    """The same streams as `robot_mcap` as ROS 2 messages (cdr): /cam/compressed
    (sensor_msgs/CompressedImage, JPEG), /ee_pose (geometry_msgs/PoseStamped), /joint_states
    (sensor_msgs/JointState with `finger` and `gripper_joint`)."""
    from mcap_ros2.writer import Writer

    with open(path, "wb") as f:
        w = Writer(f)
        schemas = {name: w.register_msgdef(name, text) for name, text in ROS2_MSGDEFS.items()}
        for t, role, value in robot_samples(duration_s, camera_hz, pose_hz, gripper_hz):
            header = {"stamp": {"sec": t // 10**9, "nanosec": t % 10**9}, "frame_id": "base"}
            if role == "camera":
                data = jpeg_of(value)
                topic, schema, msg = (
                    "/cam/compressed",
                    "sensor_msgs/msg/CompressedImage",
                    {"header": header, "format": "jpeg", "data": data},
                )
            elif role == "pose":
                pose = {"position": dict(zip("xyz", value[:3])), "orientation": dict(zip("xyzw", value[3:]))}
                topic, schema, msg = "/ee_pose", "geometry_msgs/msg/PoseStamped", {"header": header, "pose": pose}
            else:
                msg = {
                    "header": header,
                    "name": ["finger", "gripper_joint"],
                    "position": [-1.0, value],
                    "velocity": [],
                    "effort": [],
                }
                topic, schema = "/joint_states", "sensor_msgs/msg/JointState"
            w.write_message(topic, schemas[schema], msg, log_time=t + 3_000_000, publish_time=t + 3_000_000)
        w.finish()
    return path
