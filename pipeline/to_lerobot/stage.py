"""Stage `to-lerobot`: demonstration files -> one LeRobot v3.0 dataset, each demonstration an episode.

    to_lerobot(ToLerobotConfig(demos=(Path("demos"),), out=Path("dataset")))

The demonstrations are checked from their summaries first (each a demonstration file, one rate, camera
frames in all or none), so a set that cannot make one dataset is refused before anything is written. Then
each is read in turn and written by `recordings.lerobot_writer` into a work folder beside OUT, which is
renamed to OUT when complete (`pipeline.folders`); every file is named in its folder's record as
`cnep to-lerobot`'s, so `force` may replace the dataset later, and replaces nothing else.
"""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
from tqdm.contrib.logging import logging_redirect_tqdm

from cnep.outputs import record_written, writing_as
from cnep.pipeline.contract import refuse_existing, refuse_inputs
from cnep.pipeline.errors import PipelineError
from cnep.pipeline.folders import assembled_folder
from cnep.pipeline.inputs import find_demonstration_files
from cnep.pipeline.progress import progress_bar
from cnep.pipeline.to_lerobot.config import ToLerobotConfig
from cnep.recordings import Demonstration, FileSummary, read_demonstration, read_summary
from cnep.recordings.constants import KIND_DEMONSTRATION
from cnep.recordings.lerobot_columns import NS_PER_S
from cnep.recordings.lerobot_layout import TOLERANCE_S
from cnep.recordings.lerobot_writer import LerobotWriter

log = logging.getLogger(__name__)


@writing_as("to-lerobot")
def to_lerobot(config: ToLerobotConfig) -> dict:
    """Write the dataset `config.out` from `config.demos`; returns its meta/info.json."""
    out = Path(config.out)
    files = find_demonstration_files(config.demos)
    refuse_inputs([out], [*map(Path, config.demos), *files])

    def refuse() -> None:
        refuse_existing([out], config.force, "LeRobot dataset")

    refuse()
    summaries = [read_summary(path, KIND_DEMONSTRATION) for path in files]
    fps = dataset_rate(summaries, config.fps)
    camera = camera_of(summaries, config)
    off_grid = []
    with assembled_folder(out, refuse) as work, logging_redirect_tqdm():
        with LerobotWriter(work, fps, camera, config.video) as writer:
            for path in progress_bar(files, desc="to-lerobot", unit="demo", quiet=config.quiet):
                demo = read_demonstration(path)
                writer.add(demo)
                if camera is not None and not on_grid(demo, fps):
                    off_grid.append(path)
        record_written([path for path in work.rglob("*") if path.is_file()])
        info = writer.info()
    if off_grid:
        log.warning(
            "%d of %d demonstrations (%s, ...) have steps off a steady %g Hz: each frame keeps its step's own time, "
            "where cnep and LeRobot's pyav decoder find it, but LeRobot's default decoder (torchcodec) finds frames "
            "by index at the dataset's rate and may refuse them",
            len(off_grid),
            len(files),
            off_grid[0],
            fps,
        )
    log.info("%d demonstrations -> %s (%d frames at %g Hz)", len(files), out, info["total_frames"], fps)
    return info


def dataset_rate(summaries: list[FileSummary], fps: float | None) -> float:
    """The dataset's rate in Hz: `fps` if given, else the demonstrations' own, which must be one."""
    if fps is not None:
        return float(fps)
    first = summaries[0]
    for summary in summaries[1:]:
        if not np.isclose(summary.episode.fps, first.episode.fps, rtol=1e-9, atol=0.0):
            raise PipelineError(
                f"{summary.path}: recorded at {summary.episode.fps:g} Hz, {first.path} at {first.episode.fps:g} Hz; "
                f"a LeRobot dataset has one rate: give it with --fps HZ (the steps keep their own times)"
            )
    return first.episode.fps


def camera_of(summaries: list[FileSummary], config: ToLerobotConfig) -> str | None:
    """The video feature's key (None: motion only, as asked or as every demonstration is)."""
    with_frames = [s.has_frames for s in summaries]
    if config.camera_key is None or not any(with_frames):
        return None
    if not all(with_frames):
        without, having = summaries[with_frames.index(False)], summaries[with_frames.index(True)]
        raise PipelineError(
            f"{without.path}: has no camera frames, {having.path} has; a LeRobot camera has frames in every episode: "
            f'write the dataset motion only (--camera ""), or leave out the demonstrations without frames'
        )
    return config.camera_key


def on_grid(demo: Demonstration, fps: float) -> bool:
    """Whether every step is at i / fps s after the first, within LeRobot's tolerance."""
    seconds = (demo.timestamps_ns - demo.timestamps_ns[0]) / NS_PER_S  # (T,)
    return bool(np.abs(seconds - np.arange(demo.n_steps) / fps).max() <= TOLERANCE_S)
