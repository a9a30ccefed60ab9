"""Demonstrations from a LeRobot dataset folder (codebase versions v2.1 and v3.0), one per episode.

The format, as LeRobot writes it (`meta/info.json` holds `codebase_version`, `fps`, `features`,
`data_path` and `video_path` templates):

- v2.1: one Parquet file per episode (`data/chunk-{episode_chunk:03d}/episode_{episode_index:06d}.parquet`,
  chunk = episode_index // chunks_size) and one MP4 per episode and camera
  (`videos/chunk-.../{video_key}/episode_....mp4`, starting at time 0); episodes and their task
  strings in `meta/episodes.jsonl`.
- v3.0: many episodes per Parquet file and per MP4 file; `meta/episodes/chunk-*/file-*.parquet`
  gives, per episode, its task strings, `data/chunk_index`, `data/file_index` and per camera
  `videos/{key}/chunk_index`, `videos/{key}/file_index` and `videos/{key}/from_timestamp` (where the
  episode starts inside the shared video).

Each Parquet row is one step; its `timestamp` column (s from the episode start) is the step time.
The camera frame of a step is the video frame at `from_timestamp + timestamp` (within
`TOLERANCE_S`, LeRobot's own default), or for an `image` feature the image stored in the row.
Pose and gripper come from one vector column (default `observation.state`), picked by the names in
`info.json` `features[column].names` or by indices. Everything except the frames is read and checked
by `plan_lerobot` before anything is decoded, so a bad dataset is refused before any file is written.

Needs the optional extra `lerobot` (pyarrow, and PyAV for video); both are imported lazily.
"""

from __future__ import annotations

import json
import logging
import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from recordings.errors import RecordingError
from recordings.media import as_jpeg, encode_raw_image
from recordings.records import Demonstration, Episode

log = logging.getLogger(__name__)

NS_PER_S = 1_000_000_000
SUPPORTED_VERSIONS = ("v2.1", "v3.0")
TOLERANCE_S = 1e-4  # largest gap between a Parquet timestamp and its video frame (LeRobot's default)
CAMERA_DTYPES = ("video", "image")
# Pose names recognised without --pose: xyz + quaternion xyzw, or xyz + roll/pitch/yaw (radians).
DEFAULT_POSE_NAMES = (("x", "y", "z", "qx", "qy", "qz", "qw"), ("x", "y", "z", "roll", "pitch", "yaw"))
INSTALL_HINT = "pip install 'cnep-pipeline[lerobot]'"


@dataclass(frozen=True)
class LerobotMapping:
    """Which LeRobot features become frames, pose and gripper.

    camera: a `video`/`image` feature key (None: the dataset's only camera; "" for motion-only).
    state: the vector column holding pose and gripper (`observation.state`).
    pose: 7 entries (x y z qx qy qz qw) or 6 (x y z roll pitch yaw, radians, R = Rz(yaw) Ry(pitch)
        Rx(roll)), each a name from `features[state].names` or an index; None: the names above if present.
    gripper: a name or an index (None: the entry named `gripper` if there is one; "" for none, stored as 0.0).
    """

    camera: str | None = None
    state: str = "observation.state"
    pose: tuple[str, ...] | None = None
    gripper: str | None = None

    def __post_init__(self) -> None:
        if self.pose is not None and len(self.pose) not in (6, 7):
            raise RecordingError(f"LeRobot pose mapping {list(self.pose)}: give 7 entries (x y z qx qy qz qw) "
                                 f"or 6 (x y z roll pitch yaw)")


@dataclass(frozen=True)
class FrameSource:
    """Where an episode's frames are: a video file from `offset_s` on, or image bytes in Parquet rows."""

    path: Path
    offset_s: float = 0.0
    rows: np.ndarray | None = None  # row numbers in the Parquet file `path` (image features only)


@dataclass(frozen=True, eq=False)
class LerobotEpisode:
    """One episode, read and checked except for its frames.

    timestamps_ns int64 (T,) from the episode start; pose float64 (T, 7) xyz + unit quaternion xyzw;
    gripper float64 (T,); frames None for motion-only.
    """

    dataset: Path
    index: int
    task: str
    fps: float
    timestamps_ns: np.ndarray
    pose: np.ndarray
    gripper: np.ndarray
    camera: str
    frames: FrameSource | None
    extra: dict[str, str] = field(default_factory=dict)

    @property
    def episode_id(self) -> str:
        """The output name, as LeRobot names its v2.1 files: `episode_000007`."""
        return f"episode_{self.index:06d}"


def is_lerobot_dataset(path: str | os.PathLike) -> bool:
    """True for a folder with a `meta/info.json` that states a `codebase_version`."""
    info = Path(path) / "meta" / "info.json"
    if not info.is_file():
        return False
    try:
        return "codebase_version" in json.loads(info.read_text())
    except (OSError, ValueError):
        return False


def _imports() -> tuple[Any, Any]:
    try:
        import pyarrow
        import pyarrow.parquet
    except ImportError:
        raise RecordingError(f"reading LeRobot datasets needs pyarrow: {INSTALL_HINT}") from None
    return pyarrow, pyarrow.parquet


def _read_info(root: Path) -> dict:
    path = root / "meta" / "info.json"
    try:
        info = json.loads(path.read_text())
    except FileNotFoundError:
        raise RecordingError(f"{root}: not a LeRobot dataset (no meta/info.json)") from None
    except (OSError, ValueError) as exc:
        raise RecordingError(f"{path}: cannot read as JSON ({exc})") from None
    version = info.get("codebase_version")
    if version not in SUPPORTED_VERSIONS:
        raise RecordingError(f"{path}: codebase_version {version!r} is not supported (supported: "
                             f"{', '.join(SUPPORTED_VERSIONS)}); convert the dataset with LeRobot's conversion scripts")
    for key in ("fps", "features", "data_path"):
        if key not in info:
            raise RecordingError(f"{path}: no {key!r} entry; is this a LeRobot {version} dataset?")
    return info


def _choose_camera(info: dict, wanted: str | None, where: Path) -> str:
    cameras = sorted(k for k, f in info["features"].items() if f.get("dtype") in CAMERA_DTYPES)
    if wanted == "":
        return ""
    if wanted is None:
        if len(cameras) == 1:
            return cameras[0]
        if not cameras:
            raise RecordingError(f"{where}: the dataset has no camera feature (dtype video or image); "
                                 f'ingest it motion-only with --camera ""')
        raise RecordingError(f"{where}: the dataset has {len(cameras)} cameras {cameras}; choose one with --camera KEY")
    if wanted not in cameras:
        raise RecordingError(f"{where}: no camera {wanted!r} in the dataset (cameras: {cameras}); choose one with "
                             f"--camera KEY")
    return wanted


def _vector_names(feature: dict) -> list[str] | None:
    """The per-entry names of a vector feature, or None when `names` does not name each entry."""
    names, shape = feature.get("names"), feature.get("shape") or [0]
    if isinstance(names, dict) and len(names) == 1:
        names = next(iter(names.values()))
    if isinstance(names, list) and len(names) == shape[0] and all(isinstance(n, str) for n in names):
        return names
    return None


def _index_of(entry: str, names: list[str] | None, width: int, column: str, where: Path) -> int:
    if names is not None and entry in names:
        return names.index(entry)
    if entry.lstrip("-").isdigit():
        index = int(entry)
        if 0 <= index < width:
            return index
        raise RecordingError(f"{where}: index {index} is outside {column!r}, a vector of {width} values; "
                             f"the pose/gripper mapping needs a longer state vector or other indices")
    raise RecordingError(f"{where}: {column!r} has no entry named {entry!r} (names: {names}); map it with "
                         f"--pose/--gripper by name or index")


@dataclass(frozen=True)
class _Columns:
    """Indices into the state vector: pose (6 or 7) and gripper (None: no gripper)."""

    pose: tuple[int, ...]
    gripper: int | None
    described: str


def _resolve_columns(info: dict, mapping: LerobotMapping, where: Path) -> _Columns:
    feature = info["features"].get(mapping.state)
    if feature is None:
        vectors = sorted(k for k, f in info["features"].items() if f.get("dtype") in ("float32", "float64"))
        raise RecordingError(f"{where}: no feature {mapping.state!r} (vector features: {vectors}); choose the column "
                             f"with --state-column")
    width = int((feature.get("shape") or [1])[0])
    names = _vector_names(feature)
    pose = mapping.pose
    if pose is None:
        lowered = [n.lower() for n in names] if names else []
        for candidate in DEFAULT_POSE_NAMES:
            if all(c in lowered for c in candidate):
                pose = tuple(names[lowered.index(c)] for c in candidate)
                break
        else:
            raise RecordingError(f"{where}: cannot tell which entries of {mapping.state!r} are the end-effector pose "
                                 f"(names: {names}); give them with --pose x,y,z,qx,qy,qz,qw (or x,y,z,roll,pitch,yaw) "
                                 f"as names or indices")
    pose_idx = tuple(_index_of(e, names, width, mapping.state, where) for e in pose)
    gripper = mapping.gripper
    if gripper is None:
        gripper = "gripper" if names and "gripper" in names else None
        if gripper is None:
            raise RecordingError(f"{where}: no entry named 'gripper' in {mapping.state!r} (names: {names}); give it "
                                 f'with --gripper NAME|INDEX, or --gripper "" for none')
    grip_idx = _index_of(gripper, names, width, mapping.state, where) if gripper else None
    described = f"{mapping.state}[{','.join(pose)}]" + (f", gripper {mapping.state}[{gripper}]" if gripper else "")
    return _Columns(pose_idx, grip_idx, described)


def quaternion_from_rpy(rpy: np.ndarray) -> np.ndarray:
    """Roll, pitch, yaw in radians (N, 3) -> unit quaternions xyzw (N, 4) of R = Rz(yaw) Ry(pitch) Rx(roll)."""
    half = rpy / 2.0
    cr, cp, cy = np.cos(half).T
    sr, sp, sy = np.sin(half).T
    return np.stack([sr * cp * cy - cr * sp * sy,
                     cr * sp * cy + sr * cp * sy,
                     cr * cp * sy - sr * sp * cy,
                     cr * cp * cy + sr * sp * sy], axis=1)


def _vectors(table: Any, column: str, where: str) -> np.ndarray:
    """A list-valued (or scalar) Parquet column -> (N, D) float64."""
    values = table.column(column).to_pylist()
    try:
        array = np.asarray(values, dtype=np.float64)
    except (TypeError, ValueError):
        raise RecordingError(f"{where}: column {column!r} does not hold vectors of one length") from None
    return array.reshape(len(values), -1)


def _motion(table: Any, columns: _Columns, state: str, where: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(timestamps_ns (T,), pose (T, 7), gripper (T,)) of an episode's rows, checked."""
    for needed in ("timestamp", state):
        if needed not in table.column_names:
            raise RecordingError(f"{where}: no column {needed!r} (columns: {table.column_names})")
    seconds = _vectors(table, "timestamp", where)[:, 0]
    vectors = _vectors(table, state, where)  # (T, D)
    needed_width = max(columns.pose + ((columns.gripper,) if columns.gripper is not None else ())) + 1
    if vectors.shape[1] < needed_width:
        raise RecordingError(f"{where}: {state!r} holds {vectors.shape[1]} values per row, the pose/gripper mapping "
                             f"reads index {needed_width - 1}")
    if not (np.isfinite(seconds).all() and np.isfinite(vectors).all()):
        raise RecordingError(f"{where}: NaN or infinite values in 'timestamp' or {state!r}")
    times = np.round(seconds * NS_PER_S).astype(np.int64)  # (T,)
    if times[0] < 0 or (np.diff(times) <= 0).any():
        raise RecordingError(f"{where}: 'timestamp' must start at >= 0 s and increase strictly")
    raw = vectors[:, list(columns.pose)]  # (T, 6 or 7)
    quat = raw[:, 3:] if raw.shape[1] == 7 else quaternion_from_rpy(raw[:, 3:])
    norms = np.linalg.norm(quat, axis=1)
    if (norms < 1e-6).any():
        raise RecordingError(f"{where}: row {int(np.argmax(norms < 1e-6))} has a zero quaternion")
    pose = np.concatenate([raw[:, :3], quat / norms[:, None]], axis=1)  # (T, 7)
    gripper = vectors[:, columns.gripper] if columns.gripper is not None else np.zeros(len(times))
    return times, pose, gripper


def _read_parquet(path: Path, columns: list[str] | None = None) -> Any:
    _, pq = _imports()
    if not path.is_file():
        raise RecordingError(f"{path}: missing data file of the LeRobot dataset")
    try:
        return pq.read_table(path, columns=columns)
    except Exception as exc:  # pyarrow raises several unrelated types for bad files and missing columns
        raise RecordingError(f"{path}: cannot read as Parquet ({exc})") from None


def _episodes_v21(root: Path) -> list[dict]:
    path = root / "meta" / "episodes.jsonl"
    try:
        lines = [line for line in path.read_text().splitlines() if line.strip()]
        return sorted((json.loads(line) for line in lines), key=lambda e: e["episode_index"])
    except FileNotFoundError:
        raise RecordingError(f"{root}: a v2.1 dataset needs meta/episodes.jsonl") from None
    except (ValueError, KeyError, TypeError) as exc:
        raise RecordingError(f"{path}: cannot read the episode list ({exc})") from None


def _episodes_v30(root: Path) -> list[dict]:
    files = sorted((root / "meta" / "episodes").glob("chunk-*/file-*.parquet"))
    if not files:
        raise RecordingError(f"{root}: a v3.0 dataset needs meta/episodes/chunk-*/file-*.parquet")
    rows = [row for f in files for row in _read_parquet(f).to_pylist()]
    if any("episode_index" not in r for r in rows):
        raise RecordingError(f"{files[0]}: episode rows without 'episode_index'")
    return sorted(rows, key=lambda e: e["episode_index"])


def _task(entry: dict) -> str:
    tasks = entry.get("tasks") or []
    return " | ".join(str(t) for t in tasks) if isinstance(tasks, list) else str(tasks)


def plan_lerobot(root: str | os.PathLike, mapping: LerobotMapping = LerobotMapping()) -> list[LerobotEpisode]:
    """Read and check every episode of the dataset at `root` (all but the frames), in episode order."""
    root = Path(root)
    info = _read_info(root)
    version = info["codebase_version"]
    camera = _choose_camera(info, mapping.camera, root / "meta" / "info.json")
    columns = _resolve_columns(info, mapping, root / "meta" / "info.json")
    is_video = bool(camera) and info["features"][camera]["dtype"] == "video"
    if is_video and "video_path" not in info:
        raise RecordingError(f"{root / 'meta' / 'info.json'}: camera {camera!r} is a video but there is no 'video_path'")
    entries = _episodes_v21(root) if version == "v2.1" else _episodes_v30(root)
    if not entries:
        raise RecordingError(f"{root}: the dataset lists no episodes")
    chunks_size = int(info.get("chunks_size", 1000))
    cached: dict[Path, Any] = {}  # v3.0: one data file holds many episodes
    planned = []
    for entry in entries:
        index = int(entry["episode_index"])
        if version == "v2.1":
            chunk = index // chunks_size
            data = root / info["data_path"].format(episode_chunk=chunk, episode_index=index)
            video = root / info["video_path"].format(episode_chunk=chunk, video_key=camera, episode_index=index) \
                if is_video else None
            offset = 0.0
        else:
            data = root / info["data_path"].format(chunk_index=entry["data/chunk_index"],
                                                   file_index=entry["data/file_index"])
            if is_video:
                prefix = f"videos/{camera}/"
                if prefix + "from_timestamp" not in entry:
                    raise RecordingError(f"{root}: meta/episodes has no '{prefix}from_timestamp' for episode {index}")
                video = root / info["video_path"].format(video_key=camera, chunk_index=entry[prefix + "chunk_index"],
                                                         file_index=entry[prefix + "file_index"])
                offset = float(entry[prefix + "from_timestamp"])
            else:
                video, offset = None, 0.0
        if data not in cached:
            cached.clear()
            cached[data] = _read_parquet(data)
        table = cached[data]
        rows = np.arange(table.num_rows)
        if "episode_index" in table.column_names:
            rows = rows[np.asarray(table.column("episode_index").to_pylist()) == index]
        where = f"{data} (episode {index})"
        if len(rows) == 0:
            raise RecordingError(f"{where}: the episode has no frames (no rows); remove it from the dataset or fix "
                                 f"its data file")
        if len(rows) < 2:
            raise RecordingError(f"{where}: the episode has only 1 frame; a demonstration needs at least 2")
        times, pose, gripper = _motion(table.take(rows), columns, mapping.state, where)
        if video is not None and not video.is_file():
            raise RecordingError(f"{video}: missing video of camera {camera!r} for episode {index}")
        frames = None
        if camera:
            frames = FrameSource(video, offset) if video is not None else FrameSource(data, rows=rows)
        extra = {"format": f"lerobot {version}", "episode_index": str(index), "camera": camera or "none",
                 "columns": columns.described, "frame_times": "Parquet timestamp" + (" + video offset" if video else ""),
                 "interpolation": "none"}
        planned.append(LerobotEpisode(root, index, _task(entry), float(info["fps"]), times, pose, gripper, camera,
                                      frames, extra))
    return planned


def video_frames_at(path: Path, times_s: np.ndarray, tolerance_s: float = TOLERANCE_S) -> list[bytes]:
    """JPEG frames of the video at `path` whose time is within `tolerance_s` of each of `times_s` (T,) ascending."""
    try:
        import av
    except ImportError:
        raise RecordingError(f"{path}: decoding LeRobot videos needs PyAV: {INSTALL_HINT}") from None
    frames: list[bytes] = []
    try:
        with av.open(str(path)) as container:
            stream = container.streams.video[0]
            if times_s[0] > 0:  # the keyframe at or before the first wanted frame
                container.seek(int(max(times_s[0] - 1.0, 0.0) / stream.time_base), stream=stream, backward=True)
            for frame in container.decode(stream):
                t = float(frame.time)
                if t < times_s[len(frames)] - tolerance_s:
                    continue
                if abs(t - times_s[len(frames)]) > tolerance_s:
                    break  # the wanted time fell between two frames
                frames.append(encode_raw_image(frame.to_ndarray(format="bgr24"), f"{path} at {t:.4f} s"))
                if len(frames) == len(times_s):
                    break
    except av.error.FFmpegError as exc:
        raise RecordingError(f"{path}: cannot decode the video ({exc})") from None
    if len(frames) < len(times_s):
        raise RecordingError(f"{path}: no video frame within {tolerance_s * 1e3:g} ms of {times_s[len(frames)]:.4f} s "
                             f"(frame {len(frames)} of {len(times_s)}); the video and the Parquet timestamps disagree")
    return frames


def _parquet_images(source: FrameSource, camera: str) -> list[bytes]:
    table = _read_parquet(source.path, [camera]).take(source.rows)
    frames = []
    for row, cell in zip(source.rows, table.column(camera).to_pylist()):
        data = cell.get("bytes") if isinstance(cell, dict) else cell
        if not data:
            raise RecordingError(f"{source.path}: row {row} of {camera!r} holds no image bytes")
        frames.append(as_jpeg(data, f"{source.path} row {row} {camera}"))
    return frames


def demonstration_from_lerobot(episode: LerobotEpisode, task: str = "") -> Demonstration:
    """The demonstration of a planned episode (decodes its frames); `task` overrides the episode's task string."""
    frames = None
    if episode.frames is not None:
        if episode.frames.rows is None:
            times_s = episode.frames.offset_s + episode.timestamps_ns / NS_PER_S  # (T,)
            frames = video_frames_at(episode.frames.path, times_s)
        else:
            frames = _parquet_images(episode.frames, episode.camera)
    return Demonstration(
        episode=Episode(episode.episode_id, fps=episode.fps, task=task or episode.task, source=str(episode.dataset),
                        extra=episode.extra),
        timestamps_ns=episode.timestamps_ns,
        pose=episode.pose,
        gripper=episode.gripper,
        frames=frames,
    )
