"""Inputs of the train stage: trajectory files found, hashed, read once and checked to fit together."""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cnep.pipeline.errors import PipelineError, listed
from cnep.pipeline.identity import check_identities
from cnep.recordings import Trajectory, read_trajectory
from cnep.recordings.constants import BLOCK_GRIPPER
from cnep.runtime.gripper import GripperCommand
from cnep.runtime.manifest import file_sha256
from cnep.runtime.timebase import TimeBase

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TrainingFile:
    """One trajectory file trained on: where, its sha256 (hex), episode id, steps, seconds from its first to its
    last step, (T, width) data, and its gripper block's columns (the recording's unit; None without one)."""

    path: Path
    sha256: str
    episode_id: str
    n_steps: int
    duration_s: float
    data: np.ndarray
    gripper: np.ndarray | None = None

    def describe(self) -> dict:
        """JSON-able entry for config.json (the data itself is left out)."""
        return {
            "path": str(self.path.resolve()),
            "sha256": self.sha256,
            "episode_id": self.episode_id,
            "n_steps": self.n_steps,
        }


@dataclass(frozen=True)
class TrainingSet:
    """Trajectory files of one width and one feature extractor ({} for motion-only files)."""

    files: tuple[TrainingFile, ...]
    width: int
    extractor: dict[str, str]

    def time_base(self) -> TimeBase:
        """The demonstrations' median duration and step period: how a robot's seconds map to the model's t (of the
        demonstrations of 2 steps or more: one step has no duration)."""
        timed = [f for f in self.files if f.n_steps >= 2]
        return TimeBase.from_demonstrations([f.duration_s for f in timed], [f.n_steps for f in timed])

    def gripper_command(self) -> GripperCommand | None:
        """The two-state gripper's command chosen from the demonstrations' gripper values (runtime.gripper); None
        when the files have no gripper block."""
        if any(f.gripper is None for f in self.files):
            return None
        return GripperCommand.from_demonstrations(np.concatenate([f.gripper.reshape(-1) for f in self.files]))


def load_training_set(paths: Sequence[Path]) -> TrainingSet:
    """Read every file once (the recording layer validates it) and require one width and one extractor."""
    files, extractors, widths = [], {}, {}
    for path in paths:
        trajectory = read_trajectory(path)
        files.append(_training_file(path, trajectory))
        extractors[path] = trajectory.extractor or {}
        widths.setdefault(trajectory.width, []).append(path)
    if len(widths) > 1:
        described = "; ".join(
            f"{len(files_)} file(s) {width} columns wide: {listed(files_)}"
            for width, files_ in sorted(widths.items(), key=lambda item: -len(item[1]))
        )
        raise PipelineError(
            f"trajectory files have different column layouts and cannot be trained together: "
            f"{described}; train on files of one kind (with features, or motion-only)"
        )
    extractor = check_identities(extractors)
    return TrainingSet(files=tuple(files), width=next(iter(widths)), extractor=extractor)


def _training_file(path: Path, trajectory: Trajectory) -> TrainingFile:
    return TrainingFile(
        path=Path(path),
        sha256=file_sha256(path),
        episode_id=trajectory.episode.episode_id,
        n_steps=trajectory.n_steps,
        duration_s=float(trajectory.timestamps_ns[-1] - trajectory.timestamps_ns[0]) / 1e9,
        data=trajectory.data,
        gripper=trajectory.data[:, slice(*trajectory.blocks[BLOCK_GRIPPER])]
        if BLOCK_GRIPPER in trajectory.blocks
        else None,
    )
