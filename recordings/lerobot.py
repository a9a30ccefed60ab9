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

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cnep.recordings.constants import EPISODE_CAMERA, NO_CAMERA
from cnep.recordings.errors import RecordingError
from cnep.recordings.lerobot_columns import (
    NS_PER_S,
    LerobotMapping,
    StateColumns,
    motion_of_rows,
    resolve_columns,
)
from cnep.recordings.lerobot_layout import (
    CAMERA_DTYPES,
    EPISODES_DIR,
    EPISODES_V21,
    INFO_PATH,
    INSTALL_HINT,
    SUPPORTED_VERSIONS,
    TOLERANCE_S,
)
from cnep.recordings.media import as_jpeg, video_frames_at
from cnep.recordings.records import Demonstration, Episode
from cnep.runtime.jsonfile import parse_json, read_json


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
    """True for a folder with a `meta/info.json` that states a `codebase_version`.

    An `info.json` that cannot be read as JSON is a RecordingError naming it: the folder looks like a LeRobot
    dataset whose description is damaged, and reading it as other files would only mislead.
    """
    info = Path(path) / INFO_PATH
    if not info.is_file():
        return False
    try:
        data = read_json(info)
    except (OSError, ValueError) as exc:
        raise RecordingError(
            f"{info}: cannot read as JSON ({exc}); a LeRobot dataset's meta/info.json must be valid JSON: restore it "
            f"from the dataset's source"
        ) from None
    return isinstance(data, dict) and "codebase_version" in data


def _parquet() -> Any:
    """The pyarrow.parquet module (imported lazily: an optional extra)."""
    try:
        import pyarrow.parquet
    except ImportError:
        raise RecordingError(f"reading LeRobot datasets needs pyarrow: {INSTALL_HINT}") from None
    return pyarrow.parquet


def _read_info(root: Path) -> dict:
    path = root / INFO_PATH
    try:
        info = read_json(path)
    except FileNotFoundError:
        raise RecordingError(f"{root}: not a LeRobot dataset (no meta/info.json)") from None
    except (OSError, ValueError) as exc:
        raise RecordingError(f"{path}: cannot read as JSON ({exc})") from None
    if not isinstance(info, dict):
        raise RecordingError(f"{path}: holds no JSON object; a LeRobot dataset's meta/info.json describes it")
    version = info.get("codebase_version")
    if version not in SUPPORTED_VERSIONS:
        raise RecordingError(
            f"{path}: codebase_version {version!r} is not supported (supported: "
            f"{', '.join(SUPPORTED_VERSIONS)}); convert the dataset with LeRobot's conversion scripts"
        )
    for key, kind in (("fps", (int, float)), ("features", dict), ("data_path", str)):
        if key not in info:
            raise RecordingError(f"{path}: no {key!r} entry; is this a LeRobot {version} dataset?")
        if not isinstance(info[key], kind) or isinstance(info[key], bool):
            raise RecordingError(f"{path}: {key!r} is {str(info[key])[:60]!r}, not what LeRobot {version} writes there")
    odd = [name for name, feature in info["features"].items() if not isinstance(feature, dict)]
    if odd:
        raise RecordingError(f"{path}: feature {odd[0][:60]!r} is no JSON object; is this a LeRobot {version} dataset?")
    return info


def _choose_camera(info: dict, wanted: str | None, where: Path) -> str:
    cameras = sorted(k for k, f in info["features"].items() if f.get("dtype") in CAMERA_DTYPES)
    if wanted == "":
        return ""
    if wanted is None:
        if len(cameras) <= 1:
            return cameras[0] if cameras else ""  # no camera: motion only
        raise RecordingError(f"{where}: the dataset has {len(cameras)} cameras {cameras}; choose one with --camera KEY")
    if wanted not in cameras:
        raise RecordingError(
            f"{where}: no camera {wanted!r} in the dataset (cameras: {cameras}); choose one with --camera KEY"
        )
    return wanted


def _read_parquet(path: Path, columns: list[str] | None = None) -> Any:
    pq = _parquet()
    if not path.is_file():
        raise RecordingError(f"{path}: missing data file of the LeRobot dataset")
    try:
        return pq.read_table(path, columns=columns)
    except Exception as exc:  # pyarrow raises several unrelated types for bad files and missing columns
        raise RecordingError(f"{path}: cannot read as Parquet ({exc})") from None


def _motion_table(path: Path, columns: StateColumns) -> tuple[Any, np.ndarray | None]:
    """The columns of a data file that motion needs (not the images), and the episode index of each row (or None)."""
    pq = _parquet()
    if not path.is_file():
        raise RecordingError(f"{path}: missing data file of the LeRobot dataset")
    try:
        names = pq.read_schema(path).names
    except Exception as exc:  # pyarrow raises several unrelated types for bad files
        raise RecordingError(f"{path}: cannot read as Parquet ({exc})") from None
    wanted = ("timestamp", columns.state, columns.gripper_column, "episode_index")
    table = _read_parquet(path, [c for c in dict.fromkeys(wanted) if c in names])
    if "episode_index" not in names:
        return table, None
    return table, table.column("episode_index").to_numpy()


def _episodes_v21(root: Path) -> list[dict]:
    path = root / EPISODES_V21
    try:
        lines = [line for line in path.read_text().splitlines() if line.strip()]
        return sorted((parse_json(line) for line in lines), key=lambda e: e["episode_index"])
    except FileNotFoundError:
        raise RecordingError(f"{root}: a v2.1 dataset needs {EPISODES_V21}") from None
    except (ValueError, KeyError, TypeError) as exc:
        raise RecordingError(f"{path}: cannot read the episode list ({exc})") from None


def _episodes_v30(root: Path) -> list[dict]:
    files = sorted((root / EPISODES_DIR).glob("chunk-*/file-*.parquet"))
    if not files:
        raise RecordingError(f"{root}: a v3.0 dataset needs {EPISODES_DIR}/chunk-*/file-*.parquet")
    rows = [row for f in files for row in _read_parquet(f).to_pylist()]
    if any("episode_index" not in r for r in rows):
        raise RecordingError(f"{files[0]}: episode rows without 'episode_index'")
    return sorted(rows, key=lambda e: e["episode_index"])


def _task(entry: dict) -> str:
    tasks = entry.get("tasks") or []
    return " | ".join(str(t) for t in tasks) if isinstance(tasks, list) else str(tasks)


def _episode_files(
    root: Path, info: dict, version: str, entry: dict, video_key: str, chunks_size: int
) -> tuple[Path, Path | None, float]:
    """(data file, video file or None, episode start inside the video in s) of one episode."""
    index = int(entry["episode_index"])
    if version == "v2.1":  # one file per episode, grouped in chunks of chunks_size episodes
        chunk = index // chunks_size
        data = root / info["data_path"].format(episode_chunk=chunk, episode_index=index)
        if not video_key:
            return data, None, 0.0
        return (
            data,
            root / info["video_path"].format(episode_chunk=chunk, video_key=video_key, episode_index=index),
            0.0,
        )
    data = root / info["data_path"].format(chunk_index=entry["data/chunk_index"], file_index=entry["data/file_index"])
    if not video_key:
        return data, None, 0.0
    prefix = f"videos/{video_key}/"
    video = root / info["video_path"].format(
        video_key=video_key, chunk_index=entry[prefix + "chunk_index"], file_index=entry[prefix + "file_index"]
    )
    return data, video, float(entry[prefix + "from_timestamp"])


def plan_lerobot(root: str | os.PathLike, mapping: LerobotMapping = LerobotMapping()) -> list[LerobotEpisode]:
    """Read and check every episode of the dataset at `root` (all but the frames), in episode order."""
    root = Path(root)
    info = _read_info(root)
    version = info["codebase_version"]
    camera = _choose_camera(info, mapping.camera, root / INFO_PATH)
    columns = resolve_columns(info, mapping, root / INFO_PATH)
    is_video = bool(camera) and info["features"][camera]["dtype"] == "video"
    if is_video and "video_path" not in info:
        raise RecordingError(f"{root / INFO_PATH}: camera {camera!r} is a video but there is no 'video_path'")
    entries = _episodes_v21(root) if version == "v2.1" else _episodes_v30(root)
    if not entries:
        raise RecordingError(f"{root}: the dataset lists no episodes")
    chunks_size = int(info.get("chunks_size", 1000))
    cached: dict[Path, tuple[Any, np.ndarray | None]] = {}
    planned = []
    for entry in entries:
        index = int(entry["episode_index"])
        try:
            data, video, offset = _episode_files(root, info, version, entry, camera if is_video else "", chunks_size)
        except KeyError as exc:
            raise RecordingError(
                f"{root}: episode {index} has no {exc.args[0]!r} (meta/episodes or the path templates "
                f"of meta/info.json); is the dataset complete?"
            ) from None
        if data not in cached:  # consecutive episodes share a v3.0 data file: read it once
            cached.clear()
            cached[data] = _motion_table(data, columns)
        table, episode_of_row = cached[data]
        rows = np.arange(table.num_rows) if episode_of_row is None else np.flatnonzero(episode_of_row == index)
        where = f"{data} (episode {index})"
        if len(rows) == 0:
            raise RecordingError(
                f"{where}: the episode has no frames (no rows); remove it from the dataset or fix its data file"
            )
        if len(rows) < 2:
            raise RecordingError(f"{where}: the episode has only 1 frame; a demonstration needs at least 2")
        times, pose, gripper, notes = motion_of_rows(table.take(rows), columns, where)
        if video is not None and not video.is_file():
            raise RecordingError(f"{video}: missing video of camera {camera!r} for episode {index}")
        frames = None
        if camera:
            frames = FrameSource(video, offset) if video is not None else FrameSource(data, rows=rows)
        extra = {
            "format": f"lerobot {version}",
            "episode_index": str(index),
            EPISODE_CAMERA: camera or NO_CAMERA,
            "columns": columns.described,
            "frame_times": "Parquet timestamp" + (" + video offset" if video else ""),
            "interpolation": "none",
            **notes,
        }
        planned.append(
            LerobotEpisode(root, index, _task(entry), float(info["fps"]), times, pose, gripper, camera, frames, extra)
        )
    return planned


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
            frames = video_frames_at(episode.frames.path, times_s, TOLERANCE_S)
        else:
            frames = _parquet_images(episode.frames, episode.camera)
    return Demonstration(
        episode=Episode(
            episode.episode_id,
            fps=episode.fps,
            task=task or episode.task,
            source=str(episode.dataset),
            extra=episode.extra,
        ),
        timestamps_ns=episode.timestamps_ns,
        pose=episode.pose,
        gripper=episode.gripper,
        frames=frames,
    )
