"""Inputs of the train stage: trajectory files found and checked to fit together, from their metadata alone.

Each file's summary (`recordings.read_summary`: a few small reads at its end) gives its width, extractor, episode
id, steps and duration, so the checks and the split into training and validation cost milliseconds per file; the
columns themselves are read once, by the process that trains on them (`pipeline.train.packed`).
"""

from __future__ import annotations

import logging
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path

from cnep.pipeline.errors import PipelineError, listed
from cnep.pipeline.identity import check_identities
from cnep.recordings import read_summary, read_trajectory
from cnep.recordings.constants import EPISODE_CAMERA, KIND_TRAJECTORY, NO_CAMERA
from cnep.runtime.frames import decode_frame
from cnep.runtime.timebase import TimeBase

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class TrainingFile:
    """One trajectory file trained on: where, its episode id, steps, seconds from its first to its last step, its
    episode's task ("" for none: `pipeline.train.experts` names experts by the tasks) and the observation key of the
    camera its episode names ("" for none: a LeRobot dataset's is kept by `cnep ingest`)."""

    path: Path
    episode_id: str
    n_steps: int
    duration_s: float
    task: str = ""
    camera: str = ""
    views: int = 0  # views of its features it also holds (perception.views)

    def describe(self, sha256: str, held: int = 0) -> dict:
        """JSON-able entry for config.json, with the file's `sha256` (hex) and the steps it is `held` at its last
        step (pipeline.train.hold)."""
        return {
            "path": str(self.path.resolve()),
            "sha256": sha256,
            "episode_id": self.episode_id,
            "n_steps": self.n_steps,
            "task": self.task,
            **({"views": self.views} if self.views else {}),
            **({"held_steps": held} if held else {}),
        }


@dataclass(frozen=True)
class TrainingSet:
    """Trajectory files of one width and one feature extractor ({} for motion-only files)."""

    files: tuple[TrainingFile, ...]
    width: int
    extractor: dict[str, str]

    def time_base(self, holds: Mapping[int, int] | None = None) -> TimeBase:
        """The demonstrations' median duration and step period: how a robot's seconds map to the model's t (of the
        demonstrations of 2 steps or more: one step has no duration); `holds`: file index -> steps it is trained
        held at its last step (pipeline.train.hold), each lasting its own step period."""
        holds = holds or {}
        timed = [(i, f) for i, f in enumerate(self.files) if f.n_steps >= 2]
        durations = [f.duration_s * (f.n_steps - 1 + holds.get(i, 0)) / (f.n_steps - 1) for i, f in timed]
        return TimeBase.from_demonstrations(durations, [f.n_steps + holds.get(i, 0) for i, f in timed])

    def tasks(self) -> list[str]:
        """The tasks the demonstrations' episodes name, sorted ([] where none names one)."""
        return sorted({f.task for f in self.files if f.task})

    def camera_key(self) -> str | None:
        """The observation key of the camera every demonstration's episode names, None where they name none or
        several (a policy then reads any one image)."""
        named = {f.camera for f in self.files}
        key = named.pop() if len(named) == 1 else ""
        return key if key not in ("", NO_CAMERA) else None


def frame_size(path: Path) -> tuple[int, int] | None:
    """(height, width) in pixels of the first camera frame of the trajectory file `path`; None if it has no frames."""
    frames = read_trajectory(path).frames
    frame = decode_frame(frames[0]) if frames else None
    if frames and frame is None:
        raise PipelineError(f"{path}: its first camera frame does not decode; extract it again")
    return None if frame is None else (int(frame.shape[0]), int(frame.shape[1]))


def load_training_set(paths: Sequence[Path]) -> TrainingSet:
    """Every file's summary, requiring one width and one extractor."""
    files, extractors, widths = [], {}, {}
    for path in paths:
        summary = read_summary(path, KIND_TRAJECTORY)
        episode = summary.episode
        camera = episode.extra.get(EPISODE_CAMERA, "")
        files.append(
            TrainingFile(
                Path(path),
                episode.episode_id,
                summary.n_steps,
                summary.duration_ns / 1e9,
                episode.task,
                camera,
                summary.views,
            )
        )
        extractors[path] = summary.extractor
        widths.setdefault(summary.width, []).append(path)
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
