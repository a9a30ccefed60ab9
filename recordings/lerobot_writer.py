"""Demonstrations -> a LeRobot v3.0 dataset, laid out as LeRobot's own recorder writes one (pyarrow and PyAV; the
`lerobot` package is not needed).

    with LerobotWriter(root, fps=10, camera="observation.images.rgb") as writer:
        for demo in demonstrations:
            writer.add(demo)

`root` (a new or empty folder) holds the complete dataset when the block ends; an error in the block removes
what was written. Each demonstration is one episode, its steps rows of `data/` (T steps):

    observation.state  float32 (T, 8)  x y z (m), qx qy qz qw, gripper: the demonstration's pose and gripper
    action             float32 (T, 8)  the next step's pose and this step's gripper (the last step keeps its pose)
    timestamp          float32 (T,)    s since the episode's first step, as recorded (not resampled)
    frame_index, episode_index, index, task_index   int64

The action's gripper is the demonstration's own value at that step: a gripper read from a recording's
command (a LeRobot dataset's `action`, `recordings.lerobot_columns`) stays that command, what a policy
learns and what reading the dataset back takes. Names of both vectors: `runtime.spec.STATE_NAMES`.
The camera's frames, if any, are the video feature `camera` (`lerobot_video`), each frame at its step's
time; the episode's task is its `Episode.task`. Values are stored as float32 and times as float32
seconds, LeRobot's types: a value comes back as its float32 rounding, a time within half a float32 step
(0.5 us in episodes up to 16 s long, 1 us up to 32 s).
"""

from __future__ import annotations

import contextlib
import json
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from cnep.recordings.errors import RecordingError
from cnep.recordings.lerobot_columns import NS_PER_S
from cnep.recordings.lerobot_layout import (
    ACTION,
    CHUNKS_SIZE,
    CODEBASE_VERSION,
    DATA_FILE_MB,
    DATA_PATH,
    EPISODES_PATH,
    INDEX_FEATURES,
    INFO_PATH,
    INSTALL_HINT,
    STATS_PATH,
    TASKS_PATH,
    VIDEO_FILE_MB,
    VIDEO_PATH,
    next_file,
)
from cnep.recordings.lerobot_stats import ImageStats, vector_stats
from cnep.recordings.lerobot_video import VideoFile, VideoSettings
from cnep.recordings.records import Demonstration
from cnep.runtime.constants import STATE_KEY
from cnep.runtime.frames import decode_frame
from cnep.runtime.spec import STATE_NAMES


def _pyarrow() -> tuple[Any, Any]:
    """pyarrow and pyarrow.parquet (imported lazily: an optional extra)."""
    try:
        import pyarrow
        import pyarrow.parquet
    except ImportError:
        raise RecordingError(f"writing LeRobot datasets needs pyarrow: {INSTALL_HINT}") from None
    return pyarrow, pyarrow.parquet


def step_columns(demo: Demonstration) -> dict[str, np.ndarray]:
    """The demonstration's per-step columns: timestamp (T,), observation.state (T, 8) and action (T, 8), float32."""
    where = f"Demonstration {demo.episode.episode_id!r}"
    seconds = ((demo.timestamps_ns - demo.timestamps_ns[0]) / NS_PER_S).astype(np.float32)  # (T,)
    if (np.diff(seconds) <= 0).any():
        step = int(np.flatnonzero(np.diff(seconds) <= 0)[0]) + 1
        raise RecordingError(
            f"{where}: step {step} is too close to the one before it for float32 seconds (LeRobot's timestamp) "
            f"to keep them apart, at {seconds[step]:.6f} s"
        )
    state = np.concatenate([demo.pose, demo.gripper[:, None]], axis=1).astype(np.float32)  # (T, 8)
    action = state.copy()
    action[:-1, :7] = state[1:, :7]  # the pose the step moves to; the gripper stays the step's own
    return {STATE_KEY: state, ACTION: action, "timestamp": seconds}


class LerobotWriter:
    """A LeRobot v3.0 dataset being written (module docstring): `add` each demonstration, then `close`.

    fps: the dataset's rate in Hz (LeRobot keeps one per dataset); camera: the video feature's key
    (`observation.images.NAME`), or None for motion only (frames are left out); data_file_mb, video_file_mb: the
    sizes at which a data or video file is full and the next episode starts the next file.
    """

    def __init__(
        self,
        root: Path,
        fps: float,
        camera: str | None,
        video: VideoSettings = VideoSettings(),
        data_file_mb: float = DATA_FILE_MB,
        video_file_mb: float = VIDEO_FILE_MB,
    ) -> None:
        self.pa, self.pq = _pyarrow()
        self.root, self.fps, self.camera, self.video = Path(root), float(fps), camera, video
        self.data_file_mb, self.video_file_mb = data_file_mb, video_file_mb
        if self.root.exists() and any(self.root.iterdir()):
            raise RecordingError(f"{self.root}: not empty; a LeRobot dataset is written into a new or empty folder")
        self._made = not self.root.exists()
        self.root.mkdir(parents=True, exist_ok=True)
        self.episodes: list[dict] = []  # the rows of meta/episodes
        self.frames = 0  # steps written so far, every episode's
        self.tasks: dict[str, int] = {}
        self.values: dict[str, list[np.ndarray]] = {}  # feature -> each episode's values, for meta/stats.json
        self.images: list[ImageStats] = []
        self.frame_size: tuple[int, int] | None = None  # (height, width) of every frame
        self.codec = ""  # the video codec's own name, known once a video is open
        self._data: tuple[Any, tuple[int, int], float] | None = None  # writer, (chunk, file), MB so far
        self._video: tuple[VideoFile, tuple[int, int], float] | None = None  # file, (chunk, file), its end in s
        self._files = {"data": (0, 0), "video": (0, 0)}  # the next file of each
        self.closed = False  # complete: `close` has written the metadata

    def __enter__(self) -> LerobotWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        try:
            if exc_type is None:
                self.close()
        finally:
            if exc_type is not None or not self.closed:
                self.abort()

    def add(self, demo: Demonstration) -> int:
        """Write `demo` as the next episode; returns its episode index."""
        episode = len(self.episodes)
        columns = step_columns(demo)
        steps = demo.n_steps
        first = self.frames
        task = self.tasks.setdefault(demo.episode.task, len(self.tasks))
        columns |= {
            "frame_index": np.arange(steps),
            "episode_index": np.full(steps, episode),
            "index": np.arange(first, first + steps),
            "task_index": np.full(steps, task),
        }
        row = {"episode_index": episode, "tasks": [demo.episode.task], "length": steps}
        row |= self._write_rows(columns) | {"dataset_from_index": first, "dataset_to_index": first + steps}
        stats = {name: vector_stats(values) for name, values in columns.items()}
        if self.camera is not None:
            video_row, stats[self.camera] = self._write_frames(demo, columns["timestamp"])
            row |= video_row
        for name, values in columns.items():
            self.values.setdefault(name, []).append(values)
        row |= {f"stats/{name}/{key}": value.tolist() for name, s in stats.items() for key, value in s.items()}
        self.episodes.append(row | {"meta/episodes/chunk_index": 0, "meta/episodes/file_index": 0})
        self.frames += steps
        return episode

    def _write_rows(self, columns: dict[str, np.ndarray]) -> dict[str, int]:
        """Append the episode's rows to the current data file (the next one when it is full); where they went."""
        table = self.pa.table({name: self._arrow(values) for name, values in columns.items()})
        if self._data is None:
            chunk_file = self._files["data"]
            self._files["data"] = next_file(*chunk_file)
            path = self.root / DATA_PATH.format(chunk_index=chunk_file[0], file_index=chunk_file[1])
            path.parent.mkdir(parents=True, exist_ok=True)
            self._data_file = open(path, "wb")  # noqa: SIM115 - held by the Parquet writer until its file is full
            self._data = self.pq.ParquetWriter(self._data_file, table.schema, compression="snappy"), chunk_file, 0.0
        writer, chunk_file, size_mb = self._data
        writer.write_table(table)
        self._data = writer, chunk_file, size_mb + table.nbytes / 2**20
        if self._data[2] >= self.data_file_mb:
            self._close_data()
        return {"data/chunk_index": chunk_file[0], "data/file_index": chunk_file[1]}

    def _arrow(self, values: np.ndarray) -> Any:
        """A column: a fixed-size list per row for a vector (T, D), a scalar per row for (T,)."""
        if values.ndim == 1:
            return self.pa.array(values)
        return self.pa.FixedSizeListArray.from_arrays(self.pa.array(values.reshape(-1)), values.shape[1])

    def _write_frames(self, demo: Demonstration, seconds: np.ndarray) -> tuple[dict, dict[str, np.ndarray]]:
        """Encode the episode's frames into the current video file (the next one when it is full); where they went
        (its metadata row's entries) and their statistics."""
        where = f"Demonstration {demo.episode.episode_id!r}"
        if demo.frames is None:
            raise RecordingError(
                f"{where}: has no camera frames, but the dataset's camera {self.camera!r} needs them in every "
                f"episode; write the dataset motion only, or leave this demonstration out"
            )
        image_stats = ImageStats()
        for i, data in enumerate(demo.frames):
            rgb = decode_frame(data)
            if rgb is None:
                raise RecordingError(f"{where}: frame {i} does not decode; run `cnep repair` or ingest it again")
            if self.frame_size is None:
                self.frame_size = rgb.shape[:2]
            if rgb.shape[:2] != self.frame_size:
                raise RecordingError(
                    f"{where}: frame {i} is {rgb.shape[1]}x{rgb.shape[0]} pixels, the dataset's frames "
                    f"{self.frame_size[1]}x{self.frame_size[0]}; a LeRobot camera has one size: resize the frames"
                )
            video, chunk_file, start_s = self._open_video()
            video.add(rgb, start_s + float(seconds[i]))
            image_stats.add(rgb)
        self.images.append(image_stats)
        end_s = start_s + float(seconds[-1]) + 1.0 / self.fps  # the last frame shows for one step
        self._video = video, chunk_file, end_s
        prefix = f"videos/{self.camera}/"
        row = {
            prefix + "chunk_index": chunk_file[0],
            prefix + "file_index": chunk_file[1],
            prefix + "from_timestamp": start_s,
            prefix + "to_timestamp": end_s,
        }
        if video.size_mb >= self.video_file_mb:
            self._close_video()
        return row, image_stats.stats()

    def _open_video(self) -> tuple[VideoFile, tuple[int, int], float]:
        """The current video file, its (chunk, file) and where the next episode starts in it (s); opened if none is."""
        if self._video is None:
            chunk_file = self._files["video"]
            self._files["video"] = next_file(*chunk_file)
            path = self.root / VIDEO_PATH.format(
                video_key=self.camera, chunk_index=chunk_file[0], file_index=chunk_file[1]
            )
            height, width = self.frame_size
            self._video = VideoFile(path, width, height, self.fps, self.video), chunk_file, 0.0
            self.codec = self._video[0].canonical_codec
        return self._video

    def _close_data(self) -> None:
        if self._data is not None:
            self._data[0].close()
            self._data_file.close()
            self._data = None

    def _close_video(self) -> None:
        if self._video is not None:
            self._video[0].close()
            self._video = None

    def close(self) -> None:
        """Finish the data and video files and write the metadata: the dataset is complete."""
        if not self.episodes:
            raise RecordingError(f"{self.root}: no demonstrations were added; a LeRobot dataset needs one at least")
        self._close_data()
        self._close_video()
        self._write_table(EPISODES_PATH.format(chunk_index=0, file_index=0), self.pa.Table.from_pylist(self.episodes))
        self._write_tasks()
        self._write_json(STATS_PATH, {name: _listed(s) for name, s in self.dataset_stats().items()})
        self._write_json(INFO_PATH, self.info())
        self.closed = True

    def abort(self) -> None:
        """Remove everything written so far (the dataset is not complete), closing its files whatever fails."""
        if self._video is not None:
            self._video[0].abort()
        if self._data is not None:
            with contextlib.suppress(Exception):  # pyarrow raises its own types besides OSError
                self._data[0].close()
            with contextlib.suppress(OSError):
                self._data_file.close()
        self._data = self._video = None
        for path in [self.root] if self._made else list(self.root.iterdir()):
            shutil.rmtree(path, ignore_errors=True)

    def dataset_stats(self) -> dict[str, dict[str, np.ndarray]]:
        """meta/stats.json: every feature's statistics over the whole dataset."""
        stats = {name: vector_stats(np.concatenate(parts)) for name, parts in self.values.items()}
        if self.camera is not None:
            stats[self.camera] = ImageStats.merged(self.images).stats()
        return stats

    def info(self) -> dict:
        """meta/info.json: the version, counts, rate, the path templates and every feature's type and shape."""
        fps = int(self.fps) if self.fps.is_integer() else self.fps
        vector = {"dtype": "float32", "shape": [len(STATE_NAMES)], "names": list(STATE_NAMES)}
        features = {STATE_KEY: vector, ACTION: vector}
        if self.camera is not None:
            height, width = self.frame_size
            video_info = {
                "video.height": height,
                "video.width": width,
                "video.codec": self.codec,
                "video.pix_fmt": self.video.pix_fmt,
                "video.is_depth_map": False,
                "video.fps": fps,
                "video.channels": 3,
                "has_audio": False,
            }
            features[self.camera] = {
                "dtype": "video",
                "shape": [height, width, 3],
                "names": ["height", "width", "channels"],
                "info": video_info,
            }
        return {
            "codebase_version": CODEBASE_VERSION,
            "robot_type": None,
            "total_episodes": len(self.episodes),
            "total_frames": self.frames,
            "total_tasks": len(self.tasks),
            "chunks_size": CHUNKS_SIZE,
            "data_files_size_in_mb": self.data_file_mb,
            "video_files_size_in_mb": self.video_file_mb,
            "fps": fps,
            "splits": {"train": f"0:{len(self.episodes)}"},
            "data_path": DATA_PATH,
            "video_path": VIDEO_PATH if self.camera is not None else None,
            "features": features | INDEX_FEATURES,
        }

    def _write_tasks(self) -> None:
        """meta/tasks.parquet as pandas writes LeRobot's: `task_index` per task, the task strings the DataFrame's index
        (the column `__index_level_0__`, which the file's pandas metadata names as the index)."""
        table = self.pa.table({"task_index": list(self.tasks.values()), TASKS_INDEX: list(self.tasks)})
        pandas = {
            "index_columns": [TASKS_INDEX],
            "column_indexes": [
                {"name": None, "field_name": None, "pandas_type": "unicode", "numpy_type": "object",
                 "metadata": {"encoding": "UTF-8"}},
            ],
            "columns": [
                {"name": "task_index", "field_name": "task_index", "pandas_type": "int64", "numpy_type": "int64",
                 "metadata": None},
                {"name": None, "field_name": TASKS_INDEX, "pandas_type": "unicode", "numpy_type": "object",
                 "metadata": None},
            ],
            "attributes": {},
            "creator": {"library": "pyarrow", "version": self.pa.__version__},
            "pandas_version": "2.2.3",
        }  # fmt: skip
        self._write_table(TASKS_PATH, table.replace_schema_metadata({"pandas": json.dumps(pandas)}))

    def _write_table(self, relative: str, table: Any) -> None:
        path = self.root / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        self.pq.write_table(table, path, compression="snappy")

    def _write_json(self, relative: str, data: dict) -> None:
        path = self.root / relative
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_text(json.dumps(data, indent=4) + "\n")


TASKS_INDEX = "__index_level_0__"  # the column pandas stores an unnamed index in


def _listed(stats: dict[str, np.ndarray]) -> dict[str, list]:
    return {key: value.tolist() for key, value in stats.items()}
