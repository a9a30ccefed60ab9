"""LeRobot datasets (codebase v2.1 and v3.0) written with pyarrow + PyAV, with known values per step.

Episode e, step i (at i / fps s): the state vector is [x y z qx qy qz qw gripper] (or
[x y z roll pitch yaw gripper] with `rpy=True`, plus `pad` trailing joint values) from `state_of`, and
the camera frame is a uniform grey image of level `level_of(e, i)`, so a test can tell from a decoded
frame which step it belongs to. The action is two unnamed values, or with `command=True` the state's
entries (same names) with the gripper's command `command_of(e, i)`, which differs from the state's opening.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

CAMERA = "observation.images.cam"
STATE = "observation.state"


def level_of(episode: int, step: int) -> int:
    """Grey level of the frame of `step` in `episode` (steps 25 levels apart, episodes 10)."""
    return (30 + 25 * step + 10 * episode) % 256


def state_of(episode: int, step: int, rpy: bool = False, pad: int = 0) -> list[float]:
    """The state vector of a step: xyz (m), orientation (quaternion xyzw, or roll/pitch/yaw rad), gripper, pad zeros."""
    angle = 0.1 * step + 0.5 * episode  # rotation about z
    xyz = [0.1 * episode + 0.01 * step, -0.2 + 0.02 * step, 0.3]
    rot = [0.0, 0.0, angle] if rpy else [0.0, 0.0, float(np.sin(angle / 2)), float(np.cos(angle / 2))]
    return xyz + rot + [float(10 * step)] + [0.5] * pad


def command_of(episode: int, step: int) -> float:
    """The gripper command of a step: open (1.0) for the first three steps, then closed (0.0)."""
    return 1.0 if step < 3 else 0.0


def state_names(rpy: bool = False, pad: int = 0) -> list[str]:
    rot = ["roll", "pitch", "yaw"] if rpy else ["qx", "qy", "qz", "qw"]
    return ["x", "y", "z", *rot, "gripper"] + [f"joint_{k}" for k in range(pad)]


def grey_frame(level: int, size: int) -> np.ndarray:
    return np.full((size, size, 3), level, dtype=np.uint8)


def write_video(path: Path, frames: list[np.ndarray], fps: int, codec: str = "libx264") -> None:
    """Encode RGB frames (H, W, 3) uint8 as an MP4 at `fps`, frame i at i / fps s."""
    import av

    path.parent.mkdir(parents=True, exist_ok=True)
    with av.open(str(path), "w") as out:
        stream = out.add_stream(codec, rate=fps)
        stream.height, stream.width = frames[0].shape[:2]
        stream.pix_fmt = "yuv420p"
        for i, image in enumerate(frames):
            frame = av.VideoFrame.from_ndarray(image, format="rgb24")
            frame.pts = i
            out.mux(stream.encode(frame))
        out.mux(stream.encode())


def _features(image: bool, size: int, fps: int, rpy: bool, pad: int, command: bool) -> dict:
    names = state_names(rpy, pad)
    action = {"dtype": "float32", "shape": [len(names)], "names": names} if command else None
    scalar = {"dtype": "int64", "shape": [1], "names": None}
    camera = {
        "dtype": "image" if image else "video",
        "shape": [3, size, size],
        "names": ["channels", "height", "width"],
    }
    if not image:
        camera["info"] = {
            "video.fps": fps,
            "video.height": size,
            "video.width": size,
            "video.codec": "h264",
            "video.pix_fmt": "yuv420p",
        }
    return {
        CAMERA: camera,
        STATE: {"dtype": "float32", "shape": [len(names)], "names": names},
        "action": action or {"dtype": "float32", "shape": [2], "names": ["a0", "a1"]},
        "timestamp": {"dtype": "float32", "shape": [1], "names": None},
        "frame_index": scalar,
        "episode_index": scalar,
        "index": scalar,
        "task_index": scalar,
    }


def _action(episode: int, step: int, rpy: bool, pad: int) -> list[float]:
    """The state's entries with the gripper's command in place of its opening."""
    values = state_of(episode, step, rpy, pad)
    values[6 if rpy else 7] = command_of(episode, step)
    return np.float32(values).tolist()


def _rows(
    episode: int, steps: int, first_index: int, fps: int, image: bool, size: int, rpy: bool, pad: int, command: bool
) -> dict:
    import cv2

    columns = {
        STATE: [np.float32(state_of(episode, i, rpy, pad)).tolist() for i in range(steps)],
        "action": [_action(episode, i, rpy, pad) for i in range(steps)] if command else [[0.0, 1.0]] * steps,
        "timestamp": [float(np.float32(i / fps)) for i in range(steps)],
        "frame_index": list(range(steps)),
        "episode_index": [episode] * steps,
        "index": list(range(first_index, first_index + steps)),
        "task_index": [episode % 2] * steps,
    }
    if image:
        columns[CAMERA] = [
            {"bytes": cv2.imencode(".png", grey_frame(level_of(episode, i), size))[1].tobytes(), "path": None}
            for i in range(steps)
        ]
    return columns


def _table(columns: dict):
    import pyarrow as pa

    types = {
        STATE: pa.list_(pa.float32()),
        "action": pa.list_(pa.float32()),
        "timestamp": pa.float32(),
        CAMERA: pa.struct([("bytes", pa.binary()), ("path", pa.string())]),
    }
    return pa.table({k: pa.array(v, type=types.get(k, pa.int64())) for k, v in columns.items()})


TASKS = ("pick the cube", "push the cube")


def build_lerobot(
    root: Path,
    version: str = "v2.1",
    episodes: int = 2,
    steps: int = 6,
    fps: int = 10,
    size: int = 32,
    image: bool = False,
    rpy: bool = False,
    pad: int = 0,
    empty_episode: int | None = None,
    codec: str = "libx264",
    command: bool = False,
) -> Path:
    """Write a LeRobot dataset at `root` (v2.1: files per episode; v3.0: all episodes in one data and one video file).

    image: store the camera as PNG images inside the Parquet rows instead of a video.
    empty_episode: that episode gets no rows (a broken dataset).
    command: the action names the state's entries and holds the gripper's command (module docstring).
    """
    import pyarrow.parquet as pq

    root.mkdir(parents=True, exist_ok=True)
    (root / "meta").mkdir(exist_ok=True)
    lengths = [0 if e == empty_episode else steps for e in range(episodes)]
    info = {
        "codebase_version": version,
        "robot_type": "sim",
        "total_episodes": episodes,
        "total_frames": sum(lengths),
        "total_tasks": len(TASKS),
        "chunks_size": 1000,
        "fps": fps,
        "splits": {"train": f"0:{episodes}"},
        "features": _features(image, size, fps, rpy, pad, command),
    }
    per_episode = [_rows(e, n, sum(lengths[:e]), fps, image, size, rpy, pad, command) for e, n in enumerate(lengths)]
    frames = [[grey_frame(level_of(e, i), size) for i in range(n)] for e, n in enumerate(lengths)]
    if version == "v3.0":
        info["data_path"] = "data/chunk-{chunk_index:03d}/file-{file_index:03d}.parquet"
        info["video_path"] = "videos/{video_key}/chunk-{chunk_index:03d}/file-{file_index:03d}.mp4"
        merged = {k: [v for cols in per_episode for v in cols[k]] for k in per_episode[0]}
        data = root / "data" / "chunk-000" / "file-000.parquet"
        data.parent.mkdir(parents=True)
        pq.write_table(_table(merged), data)
        if not image:
            write_video(
                root / "videos" / CAMERA / "chunk-000" / "file-000.mp4", [f for fs in frames for f in fs], fps, codec
            )
        rows = []
        for e, n in enumerate(lengths):
            start = sum(lengths[:e])
            row = {
                "episode_index": e,
                "tasks": [TASKS[e % 2]],
                "length": n,
                "data/chunk_index": 0,
                "data/file_index": 0,
                "dataset_from_index": start,
                "dataset_to_index": start + n,
            }
            if not image:
                row |= {
                    f"videos/{CAMERA}/chunk_index": 0,
                    f"videos/{CAMERA}/file_index": 0,
                    f"videos/{CAMERA}/from_timestamp": start / fps,
                    f"videos/{CAMERA}/to_timestamp": (start + n) / fps,
                }
            rows.append(row)
        import pyarrow as pa

        (root / "meta" / "episodes" / "chunk-000").mkdir(parents=True)
        pq.write_table(pa.Table.from_pylist(rows), root / "meta" / "episodes" / "chunk-000" / "file-000.parquet")
        pq.write_table(
            pa.table({"task_index": list(range(len(TASKS))), "task": list(TASKS)}), root / "meta" / "tasks.parquet"
        )
    else:
        info["data_path"] = "data/chunk-{episode_chunk:03d}/episode_{episode_index:06d}.parquet"
        info["video_path"] = "videos/chunk-{episode_chunk:03d}/{video_key}/episode_{episode_index:06d}.mp4"
        for e, columns in enumerate(per_episode):
            data = root / "data" / "chunk-000" / f"episode_{e:06d}.parquet"
            data.parent.mkdir(parents=True, exist_ok=True)
            pq.write_table(_table(columns), data)
            if not image and frames[e]:
                write_video(root / "videos" / "chunk-000" / CAMERA / f"episode_{e:06d}.mp4", frames[e], fps, codec)
        (root / "meta" / "episodes.jsonl").write_text(
            "".join(
                json.dumps({"episode_index": e, "tasks": [TASKS[e % 2]], "length": n}) + "\n"
                for e, n in enumerate(lengths)
            )
        )
        (root / "meta" / "tasks.jsonl").write_text(
            "".join(json.dumps({"task_index": k, "task": t}) + "\n" for k, t in enumerate(TASKS))
        )
    (root / "meta" / "info.json").write_text(json.dumps(info, indent=4))
    return root


def gradient_frames(steps: int, size: int = 32, seed: int = 0) -> list[bytes]:
    """`steps` JPEG frames (quality 95) of smooth colour gradients that move with the step: detail a video codec keeps
    (not noise, which neither a codec nor a JPEG re-encoding keeps), different in every frame."""
    import cv2

    y, x = np.mgrid[0:size, 0:size] * (128 / size)  # (size, size), 0 .. 128
    frames = []
    for i in range(steps):
        shift = (8 * i + 20 * seed) % 120
        image = np.stack([x + shift, y + 0.5 * shift, 200 - 0.5 * (x + y)], axis=-1)  # (size, size, 3) BGR in 0 .. 248
        frames.append(cv2.imencode(".jpg", image.astype(np.uint8), [cv2.IMWRITE_JPEG_QUALITY, 95])[1].tobytes())
    return frames


def recorded_demonstration(seed: int, steps: int = 5, size: int = 32, fps: float = 10.0, task: str = "pick"):
    """A demonstration as `cnep ingest` writes one from a robot's recording: epoch times (ns) at `fps` with a few ms
    of jitter, a seeded pose and gripper (float64), gradient frames."""
    from cnep.recordings import Demonstration, Episode
    from tests.recordings.factories import random_pose

    rng = np.random.default_rng(seed)
    times = 1_700_000_000_000_000_000 + np.round((np.arange(steps) / fps + rng.uniform(0, 4e-3, steps)) * 1e9)
    return Demonstration(
        episode=Episode(f"demo_{seed}", fps=fps, task=task, source="robot"),
        timestamps_ns=times.astype(np.int64),
        pose=random_pose(steps, rng),
        gripper=rng.uniform(0.0, 0.08, steps),
        frames=gradient_frames(steps, size, seed),
    )
