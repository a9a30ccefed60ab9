"""Typed records of the two file kinds: `Demonstration` and `Trajectory`, plus `Episode` and `Event`.

Shapes (T = number of steps):
    timestamps_ns  int64   (T,)      strictly increasing, >= 0, nanoseconds
    pose           float64 (T, 7)    xyz in m, quaternion xyzw
    gripper        float64 (T,)      gripper state in the recording's units
    frames         list of T JPEG byte strings, or None (motion-only)
    data           float32 (T, D)    D = 1288 [features|pose|gripper] or 8 [pose|gripper]

Every record validates itself on construction (see `recordings.validation`), so a record that exists
is a record that can be written.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field

import numpy as np

from cnep.recordings.constants import (
    BLOCK_FEATURES,
    BLOCK_GRIPPER,
    BLOCK_POSE_QUAT,
    BLOCK_POSE_XYZ,
    BLOCKS_FULL,
    BLOCKS_MOTION,
    FEATURE_DIM,
)
from cnep.recordings.errors import RecordingError
from cnep.recordings.validation import (
    check_blocks,
    check_extractor,
    check_fps,
    check_frames,
    check_gripper,
    check_matrix,
    check_pose,
    check_timestamps,
    check_views,
)

# Keys of the `episode` metadata record that `Episode.extra` may not use.
RESERVED_EPISODE_KEYS = frozenset({"episode_id", "task", "source", "fps", "kind", "format_version"})


@dataclass(frozen=True)
class Episode:
    """Who and what a recording is: stored as the file's `episode` metadata record.

    episode_id: unique name of the demonstration (e.g. the source file stem).
    fps: nominal step rate in Hz (for a recording with varying rate, the median rate).
    task, source: free text (task label; where the data came from).
    extra: further str -> str metadata (must not reuse the reserved keys).
    """

    episode_id: str
    fps: float
    task: str = ""
    source: str = ""
    extra: Mapping[str, str] = field(default_factory=dict)

    def __post_init__(self) -> None:
        where = f"Episode {self.episode_id!r}"
        if not isinstance(self.episode_id, str) or not self.episode_id:
            raise RecordingError(f"{where}: episode_id must be a non-empty string")
        object.__setattr__(self, "fps", check_fps(self.fps, where))
        extra = dict(self.extra)
        clash = RESERVED_EPISODE_KEYS.intersection(extra)
        if clash:
            raise RecordingError(f"{where}: extra metadata may not use the reserved keys {sorted(clash)}")
        for k, v in extra.items():
            if not isinstance(k, str) or not isinstance(v, str):
                raise RecordingError(f"{where}: extra metadata must map str to str, got {k!r}: {v!r}")
        object.__setattr__(self, "extra", extra)


@dataclass(eq=False)
class Demonstration:
    """One demonstration: per-step frames (optional), end-effector pose and gripper state.

    attachments: name -> bytes of files that travel with the recording (calibration, config).
    """

    episode: Episode
    timestamps_ns: np.ndarray  # (T,) int64
    pose: np.ndarray  # (T, 7) float64, xyz + quaternion xyzw
    gripper: np.ndarray  # (T,) float64
    frames: list[bytes] | None = None  # T JPEG frames or None (motion-only)
    attachments: Mapping[str, bytes] = field(default_factory=dict)

    def __post_init__(self) -> None:
        where = f"Demonstration {self.episode.episode_id!r}"
        self.timestamps_ns = check_timestamps(self.timestamps_ns, where)
        n = self.n_steps
        self.pose = check_pose(self.pose, n, where)
        self.gripper = check_gripper(self.gripper, n, where)
        self.frames = check_frames(self.frames, n, where)
        self.attachments = dict(self.attachments)

    @property
    def n_steps(self) -> int:
        return int(self.timestamps_ns.shape[0])

    @property
    def has_frames(self) -> bool:
        return self.frames is not None


@dataclass(eq=False)
class Trajectory:
    """Per-step vectors of one demonstration: `data` (T, D) float32 with `blocks` naming its columns.

    blocks: block -> [start, stop) column range; defaults to the blocks of the width (1288 or 8).
    extractor: identity of the feature extractor (str -> str); required iff there is a feature block.
    views: (V, T, 1280) float32, the feature block under V views of the frames (perception.views), or None.
    """

    episode: Episode
    timestamps_ns: np.ndarray  # (T,) int64
    data: np.ndarray  # (T, D) float32
    blocks: Mapping[str, tuple[int, int]] | None = None
    extractor: Mapping[str, str] = field(default_factory=dict)
    frames: list[bytes] | None = None
    views: np.ndarray | None = None

    def __post_init__(self) -> None:
        where = f"Trajectory {self.episode.episode_id!r}"
        self.timestamps_ns = check_timestamps(self.timestamps_ns, where)
        self.data = check_matrix(self.data, self.n_steps, where)
        self.blocks = check_blocks(self.blocks, self.data.shape[1], where)
        self.extractor = check_extractor(self.extractor, self.blocks, where)
        self.frames = check_frames(self.frames, self.n_steps, where)
        self.views = check_views(self.views, self.n_steps, self.blocks, where)
        check_pose(self.pose, self.n_steps, where)  # non-zero quaternions

    @classmethod
    def from_demonstration(
        cls,
        demo: Demonstration,
        features: np.ndarray | None = None,
        extractor: Mapping[str, str] | None = None,
        keep_frames: bool = True,
        views: np.ndarray | None = None,
    ) -> Trajectory:
        """Build the trajectory of `demo`: features (T, 1280) or None for the 8-wide motion-only layout, and the
        features' views (V, T, 1280) or None."""
        motion = np.concatenate([demo.pose, demo.gripper[:, None]], axis=1)  # (T, 8)
        if features is None:
            data, blocks = motion, BLOCKS_MOTION
        else:
            feats = np.asarray(features, dtype=np.float32)
            if feats.shape != (demo.n_steps, FEATURE_DIM):
                raise RecordingError(
                    f"Trajectory {demo.episode.episode_id!r}: features must have shape "
                    f"({demo.n_steps}, {FEATURE_DIM}), got {feats.shape}"
                )
            data, blocks = np.concatenate([feats, motion.astype(np.float32)], axis=1), BLOCKS_FULL  # (T, 1288)
        return cls(
            episode=demo.episode,
            timestamps_ns=demo.timestamps_ns,
            data=data,
            blocks=blocks,
            extractor=extractor or {},
            frames=demo.frames if keep_frames else None,
            views=views,
        )

    @property
    def n_steps(self) -> int:
        return int(self.timestamps_ns.shape[0])

    @property
    def width(self) -> int:
        return int(self.data.shape[1])

    @property
    def has_features(self) -> bool:
        return BLOCK_FEATURES in self.blocks

    def block(self, name: str) -> np.ndarray:
        """Columns of block `name` (a view of `data`), e.g. `block("pose_xyz")` is (T, 3)."""
        if name not in self.blocks:
            raise RecordingError(
                f"Trajectory {self.episode.episode_id!r}: no block {name!r}; it has {list(self.blocks)}"
            )
        start, stop = self.blocks[name]
        return self.data[:, start:stop]

    @property
    def features(self) -> np.ndarray | None:
        """(T, 1280) float32 view, or None for a motion-only trajectory."""
        return self.block(BLOCK_FEATURES) if self.has_features else None

    @property
    def pose(self) -> np.ndarray:
        """(T, 7) float32 view: xyz + quaternion xyzw."""
        return self.data[:, self.blocks[BLOCK_POSE_XYZ][0] : self.blocks[BLOCK_POSE_QUAT][1]]

    @property
    def gripper(self) -> np.ndarray:
        """(T,) float32 view."""
        return self.block(BLOCK_GRIPPER)[:, 0]


@dataclass(frozen=True)
class Event:
    """A labelled moment (or span) of a recording, e.g. an expert switch, stored on `/events`.

    timestamp_ns: start time in ns; duration_ns: length of the span (0 for an instant);
    metadata: str -> str labels, e.g. {"kind": "expert_switch", "expert": "1"}.
    """

    timestamp_ns: int
    metadata: Mapping[str, str]
    duration_ns: int = 0

    def __post_init__(self) -> None:
        if int(self.timestamp_ns) < 0 or int(self.duration_ns) < 0:
            raise RecordingError(f"Event at {self.timestamp_ns} ns: timestamp and duration must be >= 0 ns")
        meta = dict(self.metadata)
        for k, v in meta.items():
            if not isinstance(k, str) or not isinstance(v, str):
                raise RecordingError(f"Event at {self.timestamp_ns} ns: metadata must map str to str, got {k!r}: {v!r}")
        object.__setattr__(self, "timestamp_ns", int(self.timestamp_ns))
        object.__setattr__(self, "duration_ns", int(self.duration_ns))
        object.__setattr__(self, "metadata", meta)
