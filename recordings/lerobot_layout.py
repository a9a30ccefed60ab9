"""The layout of a LeRobot dataset, as LeRobot's own code writes it: where its files are and what they are called.

The reader (`recordings.lerobot`) and the writer (`recordings.lerobot_writer`) take their names from here. A
v3.0 dataset is

    meta/info.json                                  codebase_version, fps, features, the path templates below
    meta/stats.json                                 per feature: min, max, mean, std, count, q01 ... q99
    meta/tasks.parquet                              task strings (the pandas index `task`) and their `task_index`
    meta/episodes/chunk-000/file-000.parquet        one row per episode: tasks, length, where its rows and video are
    data/chunk-000/file-000.parquet                 one row per step, many episodes per file
    videos/<camera>/chunk-000/file-000.mp4          the episodes' frames one after the other, many per file

A file takes episodes until it holds its size limit (`DATA_FILE_MB`, `VIDEO_FILE_MB`), then the next
file starts; a chunk folder holds `CHUNKS_SIZE` files.
"""

from __future__ import annotations

CODEBASE_VERSION = "v3.0"  # what the writer writes
SUPPORTED_VERSIONS = ("v2.1", CODEBASE_VERSION)  # what the reader reads
INSTALL_HINT = "pip install 'cnep-pipeline[lerobot]'"

INFO_PATH = "meta/info.json"
STATS_PATH = "meta/stats.json"
TASKS_PATH = "meta/tasks.parquet"
EPISODES_DIR = "meta/episodes"
CHUNK_FILE = "chunk-{chunk_index:03d}/file-{file_index:03d}"
EPISODES_PATH = f"{EPISODES_DIR}/{CHUNK_FILE}.parquet"
DATA_PATH = f"data/{CHUNK_FILE}.parquet"
VIDEO_PATH = "videos/{video_key}/" + CHUNK_FILE + ".mp4"
EPISODES_V21 = "meta/episodes.jsonl"  # v2.1: one JSON line per episode

CHUNKS_SIZE = 1000  # files per chunk folder
DATA_FILE_MB = 100  # a data file takes episodes until it holds this many MB (uncompressed)
VIDEO_FILE_MB = 200  # a video file takes episodes until it holds this many MB

TOLERANCE_S = 1e-4  # largest gap between a Parquet timestamp and its video frame (LeRobot's default)
CAMERA_DTYPES = ("video", "image")
ACTION = "action"  # the column of the commands a policy learns to give
QUANTILES = (0.01, 0.10, 0.50, 0.90, 0.99)  # the quantiles of meta/stats.json, as keys q01 ... q99

# The columns every dataset has besides its own features: the step's time in s from the episode start, its index in
# the episode, the episode's, its index in the dataset, and its task's.
INDEX_FEATURES = {
    "timestamp": {"dtype": "float32", "shape": [1], "names": None},
    "frame_index": {"dtype": "int64", "shape": [1], "names": None},
    "episode_index": {"dtype": "int64", "shape": [1], "names": None},
    "index": {"dtype": "int64", "shape": [1], "names": None},
    "task_index": {"dtype": "int64", "shape": [1], "names": None},
}


def next_file(chunk_index: int, file_index: int) -> tuple[int, int]:
    """The (chunk, file) after this one: the next file of the chunk, or the first of the next chunk when it is full."""
    return (chunk_index + 1, 0) if file_index == CHUNKS_SIZE - 1 else (chunk_index, file_index + 1)
