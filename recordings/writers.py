"""Writers of demonstration and trajectory files: context managers, atomic (temp name + rename).

    with DemonstrationWriter(path, episode) as w:
        for t, pose, grip, jpeg in steps:
            w.write_step(t, pose, grip, frame=jpeg)      # frame=None for every step: motion-only

    with TrajectoryWriter(path, episode, width=1288, extractor={...}) as w:
        w.write_steps(timestamps_ns, data)               # or write_step(t, row) per step

The `episode` (and `extractor`) metadata records are written when the writer opens, so they survive
a recorder killed mid-way (see `cnep repair`); the `steps` record (n_steps, start/end/duration in ns)
when it closes.
If the block raises, nothing is left at `path`.
"""

from __future__ import annotations

import json
import mimetypes
import os
from collections.abc import Mapping, Sequence
from contextlib import ExitStack
from pathlib import Path
from typing import Any

import numpy as np

from cnep.outputs import atomic_file
from cnep.recordings.constants import (
    BLOCK_FEATURES,
    BLOCK_POSE_QUAT,
    BLOCK_POSE_XYZ,
    CHANNEL_KEY_BLOCKS,
    CHANNEL_KEY_DTYPE,
    CHANNEL_KEY_VIEWS,
    CHANNEL_KEY_WIDTH,
    COMPRESSION_BY_KIND,
    FORMAT_VERSION,
    KIND_DEMONSTRATION,
    KIND_TRAJECTORY,
    METADATA_EPISODE,
    METADATA_EXTRACTOR,
    METADATA_STEPS,
    SCHEMA_GRIPPER,
    SCHEMA_IMAGE,
    SCHEMA_POSE,
    SCHEMA_TRAJECTORY,
    TOPIC_GRIPPER,
    TOPIC_IMAGE,
    TOPIC_POSE,
    TOPIC_TRAJECTORY,
    TOPIC_VIEWS,
)
from cnep.recordings.container import new_writer
from cnep.recordings.errors import RecordingError
from cnep.recordings.records import Demonstration, Episode, Trajectory
from cnep.recordings.schemas import (
    FOXGLOVE_CLASSES,
    encode_gripper,
    encode_image,
    encode_pose,
    encode_vector,
    feature_vector_schema,
    schema_data,
)
from cnep.recordings.validation import (
    check_blocks,
    check_extractor,
    check_frames,
    check_gripper,
    check_matrix,
    check_pose,
    check_timestamps,
    check_views,
)


def episode_metadata(episode: Episode, kind: str) -> dict[str, str]:
    """The `episode` metadata record of a file of `kind`."""
    return {
        "episode_id": episode.episode_id,
        "task": episode.task,
        "source": episode.source,
        "fps": repr(float(episode.fps)),
        "kind": kind,
        "format_version": FORMAT_VERSION,
        **episode.extra,
    }


def steps_metadata(timestamps_ns: Sequence[int]) -> dict[str, str]:
    """The `steps` metadata record: n_steps and start/end/duration in ns."""
    n = len(timestamps_ns)
    start, end = (int(timestamps_ns[0]), int(timestamps_ns[-1])) if n else (0, 0)
    return {"n_steps": str(n), "start_ns": str(start), "end_ns": str(end), "duration_ns": str(end - start)}


class _McapFile:
    """An open output MCAP file: schema/channel registry over the mcap Writer, atomic on close."""

    def __init__(self, path: str | os.PathLike, kind: str, episode: Episode, attachments: Mapping[str, bytes]):
        self.path = Path(path)
        self._stack = ExitStack()
        stream = self._stack.enter_context(atomic_file(self.path))
        self._schema_ids: dict[str, int] = {}
        self.channels: dict[str, int] = {}
        try:
            self.writer = new_writer(stream, COMPRESSION_BY_KIND[kind])
            for name, data in attachments.items():
                media = mimetypes.guess_type(name)[0] or "application/octet-stream"
                self.writer.add_attachment(create_time=0, log_time=0, name=name, media_type=media, data=bytes(data))
            self.writer.add_metadata(METADATA_EPISODE, episode_metadata(episode, kind))
        except BaseException as exc:  # the temporary file goes now, not when the garbage collector gets to it
            self.abort(exc)
            raise

    def channel(self, topic: str, schema_name: str, metadata: Mapping[str, str] | None = None) -> int:
        """Id of the channel of `topic`, registering it (and its schema) on first use."""
        if topic not in self.channels:
            if schema_name not in self._schema_ids:
                data = (
                    feature_vector_schema()
                    if schema_name == SCHEMA_TRAJECTORY
                    else schema_data(FOXGLOVE_CLASSES[schema_name])
                )
                self._schema_ids[schema_name] = self.writer.register_schema(
                    name=schema_name, encoding="protobuf", data=data
                )
            self.channels[topic] = self.writer.register_channel(
                topic=topic,
                message_encoding="protobuf",
                schema_id=self._schema_ids[schema_name],
                metadata=dict(metadata or {}),
            )
        return self.channels[topic]

    def add(self, channel_id: int, t_ns: int, data: bytes) -> None:
        self.writer.add_message(channel_id=channel_id, log_time=t_ns, data=data, publish_time=t_ns)

    def finish(self, metadata: Mapping[str, Mapping[str, str]]) -> None:
        """Write closing metadata, the summary and footer; rename into place."""
        for name, data in metadata.items():
            self.writer.add_metadata(name, dict(data))
        self.writer.finish()
        self._stack.close()

    def abort(self, exc: BaseException) -> None:
        """Drop the temporary file (the exception propagates to the caller)."""
        self._stack.__exit__(type(exc), exc, exc.__traceback__)


class _StepWriter:
    """Shared lifecycle of the two writers: per-step time checks, frames, atomic close."""

    kind = ""

    def __init__(self, path: str | os.PathLike, episode: Episode, attachments: Mapping[str, bytes] | None = None):
        self.path = Path(path)
        self.episode = episode
        self._attachments = dict(attachments or {})
        self._file: _McapFile | None = None
        self._times: list[int] = []
        self._with_frames: bool | None = None

    def __enter__(self) -> Any:
        self._file = _McapFile(self.path, self.kind, self.episode, self._attachments)
        self._open(self._file)
        return self

    def _open(self, f: _McapFile) -> None:
        """Register channels known up front (subclasses)."""

    def __exit__(self, exc_type: Any, exc: BaseException | None, tb: Any) -> None:
        f = self._open_file()
        if exc is None:
            try:
                self._close(f)
            except BaseException as close_exc:
                f.abort(close_exc)
                raise
        else:
            f.abort(exc)

    def _open_file(self) -> _McapFile:
        if self._file is None:
            raise RecordingError(f"{self.path}: use the writer in a `with` block")
        return self._file

    def _close(self, f: _McapFile) -> None:
        if not self._times:
            raise RecordingError(f"{self.path}: no steps were written; a recording needs at least one step")
        f.finish({METADATA_STEPS: steps_metadata(self._times)})

    def _where(self) -> str:
        return f"{self.path} (step {len(self._times)})"

    def _next_time(self, t_ns: int) -> int:
        t = int(t_ns)
        if t < 0:
            raise RecordingError(f"{self._where()}: timestamp {t} ns is negative")
        if self._times and t <= self._times[-1]:
            raise RecordingError(
                f"{self._where()}: timestamps go backwards (or repeat): {self._times[-1]} ns then {t} ns"
            )
        return t

    def _frame(self, t: int, frame: bytes | None) -> None:
        has = frame is not None
        if self._with_frames is None:
            self._with_frames = has
        elif has != self._with_frames:
            raise RecordingError(f"{self._where()}: give a frame at every step or at none (motion-only)")
        if has:
            check_frames([frame], 1, self._where())  # type: ignore[list-item]
            f = self._open_file()
            f.add(f.channel(TOPIC_IMAGE, SCHEMA_IMAGE), t, encode_image(t, frame))  # type: ignore[arg-type]

    @property
    def n_steps(self) -> int:
        return len(self._times)


class DemonstrationWriter(_StepWriter):
    """Writes a demonstration file: `/camera/rgb` (optional), `/ee/pose`, `/gripper` per step."""

    kind = KIND_DEMONSTRATION

    def _open(self, f: _McapFile) -> None:
        self._pose_ch = f.channel(TOPIC_POSE, SCHEMA_POSE)
        self._grip_ch = f.channel(TOPIC_GRIPPER, SCHEMA_GRIPPER)

    def write_step(self, t_ns: int, pose: Sequence[float], gripper: float, frame: bytes | None = None) -> None:
        """One step at `t_ns` (ns): pose (7,) xyz m + quaternion xyzw, gripper scalar, JPEG frame or None."""
        f = self._open_file()
        t = self._next_time(t_ns)
        p = check_pose(np.asarray(pose, dtype=np.float64)[None], 1, self._where())[0]
        g = check_gripper([gripper], 1, self._where())[0]
        self._frame(t, frame)
        f.add(self._pose_ch, t, encode_pose(t, p))
        f.add(self._grip_ch, t, encode_gripper(t, g))
        self._times.append(t)


class TrajectoryWriter(_StepWriter):
    """Writes a trajectory file: `/trajectory` (one packed float32 vector per step), frames optional.

    width: 1288 ([features|pose|gripper]) or 8 ([pose|gripper]); the column blocks go into the channel
    metadata. extractor: feature extractor identity (str -> str), required iff width is 1288. views: how many views
    of the feature block each step also holds on `/trajectory/views` (perception.views), 0 for none.
    """

    kind = KIND_TRAJECTORY

    def __init__(
        self,
        path: str | os.PathLike,
        episode: Episode,
        width: int,
        extractor: Mapping[str, str] | None = None,
        attachments: Mapping[str, bytes] | None = None,
        views: int = 0,
    ):
        super().__init__(path, episode, attachments)
        self.blocks = check_blocks(None, width, str(self.path))
        self.extractor = check_extractor(extractor, self.blocks, str(self.path))
        self.width = width
        if views and BLOCK_FEATURES not in self.blocks:
            raise RecordingError(f"{self.path}: feature views need a feature block; this trajectory is motion-only")
        self.views = views

    def _open(self, f: _McapFile) -> None:
        meta = {
            CHANNEL_KEY_BLOCKS: json.dumps({k: list(v) for k, v in self.blocks.items()}),
            CHANNEL_KEY_WIDTH: str(self.width),
            CHANNEL_KEY_DTYPE: "float32",
        }
        self._vec_ch = f.channel(TOPIC_TRAJECTORY, SCHEMA_TRAJECTORY, meta)
        if self.views:
            self._views_ch = f.channel(TOPIC_VIEWS, SCHEMA_TRAJECTORY, {CHANNEL_KEY_VIEWS: str(self.views)})
        if self.extractor:  # at open, like `episode`: a salvaged file still says where its features came from
            f.writer.add_metadata(METADATA_EXTRACTOR, self.extractor)

    def write_step(self, t_ns: int, vector: np.ndarray, frame: bytes | None = None) -> None:
        """One step at `t_ns` (ns): `vector` (width,) float32, JPEG frame or None."""
        self.write_steps(np.asarray([t_ns]), np.asarray(vector)[None], None if frame is None else [frame])

    def write_steps(
        self,
        timestamps_ns: np.ndarray,
        data: np.ndarray,
        frames: Sequence[bytes] | None = None,
        views: np.ndarray | None = None,
    ) -> None:
        """Several steps: timestamps (N,) int ns, data (N, width) float32, frames N JPEGs or None, and the feature
        block's views (V, N, 1280) float32, V this file's views (None where it holds none)."""
        f = self._open_file()
        where = self._where()
        ts = check_timestamps(timestamps_ns, where)
        rows = check_matrix(data, ts.shape[0], where)
        if rows.shape[1] != self.width:
            raise RecordingError(f"{where}: vector width {rows.shape[1]} does not match this file's width {self.width}")
        views = check_views(views, ts.shape[0], self.blocks, where)
        if (0 if views is None else len(views)) != self.views:
            given = "none" if views is None else len(views)
            raise RecordingError(f"{where}: {given} feature views for a file of {self.views} per step")
        pose_cols = slice(self.blocks[BLOCK_POSE_XYZ][0], self.blocks[BLOCK_POSE_QUAT][1])
        check_pose(rows[:, pose_cols], ts.shape[0], where)
        check_frames(frames, ts.shape[0], where)
        self._next_time(int(ts[0]))
        for i, t in enumerate(ts.tolist()):
            self._frame(t, None if frames is None else frames[i])
            f.add(self._vec_ch, t, encode_vector(t, rows[i]))
            if views is not None:
                f.add(self._views_ch, t, encode_vector(t, views[:, i]))
        self._times.extend(ts.tolist())


def write_demonstration(path: str | os.PathLike, demo: Demonstration) -> Path:
    """Write `demo` to `path` atomically; returns the path."""
    frames = demo.frames or [None] * demo.n_steps
    with DemonstrationWriter(path, demo.episode, demo.attachments) as w:
        for t, pose, grip, frame in zip(demo.timestamps_ns.tolist(), demo.pose, demo.gripper.tolist(), frames):
            w.write_step(t, pose, grip, frame)
    return Path(path)


def write_trajectory(path: str | os.PathLike, traj: Trajectory) -> Path:
    """Write `traj` to `path` atomically; returns the path."""
    views = 0 if traj.views is None else len(traj.views)
    with TrajectoryWriter(path, traj.episode, traj.width, traj.extractor, views=views) as w:
        w.write_steps(traj.timestamps_ns, traj.data, traj.frames, traj.views)
    return Path(path)
