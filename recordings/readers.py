"""Readers of demonstration and trajectory files (strict: CRCs validated, every field checked).

    demo = read_demonstration(path)
    traj = read_trajectory(path)
    with TrajectoryReader(path) as r:      # metadata first, data on demand
        if r.extractor == expected: traj = r.read()

Every problem raises one `RecordingError` that names the file: missing/empty/not MCAP, truncated or
corrupt (flipped byte -> CRC mismatch), missing topic or metadata, unknown `format_version`, wrong
file kind, NaN/inf, timestamps going backwards, wrong vector width.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from cnep.recordings.constants import (
    BLOCK_FEATURES,
    CHANNEL_KEY_BLOCKS,
    CHANNEL_KEY_VIEWS,
    CHANNEL_KEY_WIDTH,
    IMAGE_FORMAT,
    KIND_DEMONSTRATION,
    KIND_TRAJECTORY,
    METADATA_EPISODE,
    METADATA_EXTRACTOR,
    METADATA_STEPS,
    TOPIC_GRIPPER,
    TOPIC_IMAGE,
    TOPIC_POSE,
    TOPIC_TRAJECTORY,
    TOPIC_VIEWS,
)
from cnep.recordings.container import CORRUPTION_ERRORS, McapContents, read_mcap
from cnep.recordings.errors import RecordingError
from cnep.recordings.records import RESERVED_EPISODE_KEYS, Demonstration, Episode, Trajectory
from cnep.recordings.schemas import decode_gripper, decode_image, decode_pose, vector_payload
from cnep.recordings.validation import check_blocks, check_format_version
from cnep.runtime.jsonfile import parse_json

# (kind found, kind expected) -> what to do about it, appended to the error.
_KIND_FIXES = {
    (KIND_DEMONSTRATION, KIND_TRAJECTORY): "; run `cnep extract` on the demonstrations first and give its output",
    (KIND_TRAJECTORY, KIND_DEMONSTRATION): "; it is already extracted: give it to `cnep train` or `cnep replay`",
}


@contextlib.contextmanager
def in_file(path: Path) -> Iterator[None]:
    """Prefix RecordingErrors raised inside with the file name; turn decode failures into them."""
    try:
        yield
    except RecordingError as exc:
        text = str(exc)
        if text.startswith(str(path)):
            raise
        raise RecordingError(f"{path}: {text}") from None
    except CORRUPTION_ERRORS as exc:
        raise RecordingError(f"{path}: corrupt message ({type(exc).__name__}: {exc})") from None


def read_episode(contents: McapContents, kind: str) -> Episode:
    """The `Episode` of a file of `kind`, after checking format_version, kind and completeness."""
    path = contents.path
    meta = contents.metadata.get(METADATA_EPISODE)
    if meta is None:
        raise RecordingError(
            f"{path}: no '{METADATA_EPISODE}' metadata record, so it was not written by cnep; "
            "import a robot's recording with `cnep ingest`"
        )
    check_format_version(meta.get("format_version"), str(path))
    if meta.get("kind") != kind:
        raise RecordingError(
            f"{path}: is a {meta.get('kind')!r} file, expected a {kind!r} file"
            f"{_KIND_FIXES.get((meta.get('kind'), kind), '')}"
        )
    if METADATA_STEPS not in contents.metadata:
        raise RecordingError(
            f"{path}: no '{METADATA_STEPS}' record: the writer never closed it; salvage it with `cnep repair`"
        )
    with in_file(path):
        return Episode(
            episode_id=meta.get("episode_id", ""),
            fps=meta.get("fps"),  # type: ignore[arg-type]  # parsed and checked by Episode
            task=meta.get("task", ""),
            source=meta.get("source", ""),
            extra={k: v for k, v in meta.items() if k not in RESERVED_EPISODE_KEYS},
        )


def _timestamps(contents: McapContents, topic: str) -> tuple[list[Any], np.ndarray]:
    msgs = contents.topic_messages(topic)
    return msgs, np.fromiter((m.log_time for m in msgs), dtype=np.int64, count=len(msgs))


def _check_steps(contents: McapContents, topic: str, n: int) -> None:
    declared = contents.metadata[METADATA_STEPS].get("n_steps")
    if declared != str(n):
        raise RecordingError(
            f"{contents.path}: '{METADATA_STEPS}' record says {declared} steps but {topic} has {n} messages"
        )


def _frames(contents: McapContents, timestamps: np.ndarray) -> list[bytes] | None:
    """JPEG frames on /camera/rgb at exactly `timestamps`, or None if the file has no image topic."""
    if contents.channel_of_topic(TOPIC_IMAGE) is None:
        return None
    msgs, ts = _timestamps(contents, TOPIC_IMAGE)
    if not np.array_equal(ts, timestamps):
        raise RecordingError(f"{contents.path}: {TOPIC_IMAGE} has {len(ts)} frames not at the step times of the file")
    frames = []
    for i, m in enumerate(msgs):
        data, fmt = decode_image(m.data)
        if fmt != IMAGE_FORMAT:
            raise RecordingError(
                f"{contents.path}: frame {i} on {TOPIC_IMAGE} has format {fmt!r}, expected {IMAGE_FORMAT!r}"
            )
        frames.append(data)
    return frames


def demonstration_from(contents: McapContents) -> Demonstration:
    """Build and validate the `Demonstration` held in already-read `contents`."""
    path = contents.path
    episode = read_episode(contents, KIND_DEMONSTRATION)
    with in_file(path):
        pose_msgs, ts = _timestamps(contents, TOPIC_POSE)
        grip_msgs, grip_ts = _timestamps(contents, TOPIC_GRIPPER)
        if not np.array_equal(ts, grip_ts):
            raise RecordingError(
                f"{path}: {TOPIC_GRIPPER} ({len(grip_ts)} messages) is not at the times of {TOPIC_POSE} ({len(ts)})"
            )
        _check_steps(contents, TOPIC_POSE, len(ts))
        try:
            gripper = [decode_gripper(m.data) for m in grip_msgs]
        except KeyError as exc:
            raise RecordingError(f"{path}: a {TOPIC_GRIPPER} message has no joint {exc}") from None
        return Demonstration(
            episode=episode,
            timestamps_ns=ts,
            pose=np.array([decode_pose(m.data) for m in pose_msgs], dtype=np.float64).reshape(-1, 7),
            gripper=np.array(gripper, dtype=np.float64),
            frames=_frames(contents, ts),
            attachments={a.name: a.data for a in contents.attachments},
        )


def trajectory_from(contents: McapContents, frames: bool = True) -> Trajectory:
    """Build and validate the `Trajectory` held in already-read `contents`; `frames=False` leaves its camera frames
    unread (`Trajectory.frames` None), for readers of the columns only."""
    path = contents.path
    episode = read_episode(contents, KIND_TRAJECTORY)
    with in_file(path):
        msgs, ts = _timestamps(contents, TOPIC_TRAJECTORY)
        _check_steps(contents, TOPIC_TRAJECTORY, len(ts))
        blocks, width = channel_blocks(contents)
        payloads = [vector_payload(m.data) for m in msgs]
        for i, p in enumerate(payloads):
            if len(p) != 4 * width:
                raise RecordingError(f"{path}: wrong vector width {len(p) // 4} at step {i}; the layout says {width}")
        data = np.frombuffer(bytearray().join(payloads), dtype="<f4").reshape(len(msgs), width)  # (T, D)
        return Trajectory(
            episode=episode,
            timestamps_ns=ts,
            data=data,
            blocks=blocks,
            extractor=contents.metadata.get(METADATA_EXTRACTOR, {}),
            frames=_frames(contents, ts) if frames else None,
            views=_views(contents, ts, blocks),
        )


def _views(contents: McapContents, ts: np.ndarray, blocks: dict[str, tuple[int, int]]) -> np.ndarray | None:
    """The feature block's views (V, T, F) on `/trajectory/views`, one message per step at `ts`; None without it."""
    channel = contents.channel_of_topic(TOPIC_VIEWS)
    if channel is None:
        return None
    path = contents.path
    try:
        count = int(channel.metadata[CHANNEL_KEY_VIEWS])
    except (KeyError, ValueError):
        raise RecordingError(f"{path}: {TOPIC_VIEWS} channel metadata lacks a valid view count") from None
    a, b = blocks.get(BLOCK_FEATURES, (0, 0))
    msgs, times = _timestamps(contents, TOPIC_VIEWS)
    if not np.array_equal(times, ts):
        raise RecordingError(f"{path}: {TOPIC_VIEWS} has {len(times)} steps at other times than {TOPIC_TRAJECTORY}'s")
    payloads = [vector_payload(m.data) for m in msgs]
    for i, p in enumerate(payloads):
        if len(p) != 4 * count * (b - a):
            raise RecordingError(f"{path}: wrong view width {len(p) // 4} at step {i}; {count} views of {b - a}")
    views = np.frombuffer(bytearray().join(payloads), dtype="<f4").reshape(len(msgs), count, b - a)
    return views.transpose(1, 0, 2)  # (V, T, F)


def channel_blocks(contents: McapContents) -> tuple[dict[str, tuple[int, int]], int]:
    """(blocks, width) from the channel metadata of /trajectory, checked against the known column blocks."""
    ch = contents.require_channel(TOPIC_TRAJECTORY)
    try:
        width = int(ch.metadata[CHANNEL_KEY_WIDTH])
        blocks = parse_json(ch.metadata[CHANNEL_KEY_BLOCKS])
    except (KeyError, ValueError) as exc:
        raise RecordingError(f"{contents.path}: {TOPIC_TRAJECTORY} channel metadata lacks a valid {exc}") from None
    return check_blocks(blocks, width, str(contents.path)), width


def read_demonstration(path: str | os.PathLike) -> Demonstration:
    """Read and validate the demonstration file at `path`."""
    return demonstration_from(read_mcap(path))


def read_trajectory(path: str | os.PathLike, frames: bool = True) -> Trajectory:
    """Read and validate the trajectory file at `path`; `frames=False`: without its camera frames."""
    return trajectory_from(read_mcap(path), frames)


class _Reader:
    """Context manager: reads and checks the file on enter; `episode` and `n_steps` then; `read()`."""

    kind = ""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self._contents: McapContents | None = None

    def __enter__(self) -> Any:
        self._contents = read_mcap(self.path)
        self.episode = read_episode(self._contents, self.kind)
        with in_file(self.path):
            self.n_steps = int(self._contents.metadata[METADATA_STEPS]["n_steps"])
        return self

    def __exit__(self, *exc: Any) -> None:
        self._contents = None

    def _loaded(self) -> McapContents:
        if self._contents is None:
            raise RecordingError(f"{self.path}: reader used outside its `with` block")
        return self._contents


class DemonstrationReader(_Reader):
    """`with DemonstrationReader(path) as r: r.episode, r.n_steps, r.has_frames, r.read()`."""

    kind = KIND_DEMONSTRATION

    @property
    def has_frames(self) -> bool:
        return self._loaded().channel_of_topic(TOPIC_IMAGE) is not None

    def read(self) -> Demonstration:
        return demonstration_from(self._loaded())


class TrajectoryReader(_Reader):
    """`with TrajectoryReader(path) as r: r.episode, r.n_steps, r.blocks, r.width, r.extractor, r.read()`."""

    kind = KIND_TRAJECTORY

    def __enter__(self) -> TrajectoryReader:
        super().__enter__()
        self.blocks, self.width = channel_blocks(self._loaded())
        self.extractor = dict(self._loaded().metadata.get(METADATA_EXTRACTOR, {}))
        return self

    def read(self) -> Trajectory:
        return trajectory_from(self._loaded())
