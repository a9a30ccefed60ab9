"""Build a `Demonstration` from what robot teams record: a folder of video or numbered images plus a
CSV of pose and gripper values, or a motion-only CSV.

Time base: the CSV's time column. Frames get times as follows:
- one image per CSV row (same count): image i takes the time of row i; nothing is interpolated;
- otherwise (a video, or a different number of images): frame i is at
  `t_first_row + offset + i / frame_rate` (the video's own rate unless `frame_rate` is given);
  pose and gripper are then interpolated at the frame times (xyz and gripper linearly, the
  quaternion by slerp), and frames outside the CSV's time span are dropped (never extrapolated).
A motion-only CSV gives one step per row.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from cnep.recordings.csv_motion import CsvColumns, MotionTable, read_motion_csv
from cnep.recordings.errors import RecordingError
from cnep.recordings.interpolate import interpolate_linear, slerp
from cnep.recordings.media import VIDEO_SUFFIXES, numbered_images, read_images, read_video
from cnep.recordings.records import Demonstration, Episode

log = logging.getLogger(__name__)

NS_PER_S = 1_000_000_000


@dataclass(frozen=True)
class FrameTiming:
    """How frames map to time when they are not one per CSV row.

    frame_rate: Hz (None: the video's own rate; required for numbered images).
    offset_ms: time of the first frame after the first CSV row, in ms.
    """

    frame_rate: float | None = None
    offset_ms: float = 0.0

    def __post_init__(self) -> None:
        if self.frame_rate is not None and not (np.isfinite(self.frame_rate) and self.frame_rate > 0):
            raise RecordingError(f"frame rate (--frame-rate) must be a finite number of Hz > 0, got {self.frame_rate}")
        if not np.isfinite(self.offset_ms):
            raise RecordingError(
                f"frame offset (--frame-offset-ms) must be a finite number of ms, got {self.offset_ms}"
            )

    def times_ns(self, n_frames: int, first_row_ns: int, rate: float) -> tuple[np.ndarray, str]:
        """Times (n_frames,) int64 ns of frames at `rate` Hz after the first CSV row, and how they were made."""
        t0 = first_row_ns + round(self.offset_ms * 1e6)
        times = t0 + np.round(np.arange(n_frames) * (NS_PER_S / rate)).astype(np.int64)  # (F,)
        return times, f"first CSV time + {self.offset_ms} ms + i / {rate} Hz"


def median_rate(timestamps_ns: np.ndarray) -> float:
    """Median step rate in Hz of strictly increasing ns timestamps (>= 2 of them)."""
    return float(NS_PER_S / np.median(np.diff(timestamps_ns)))


def motion_at(
    times_ns: np.ndarray,
    pose_t: np.ndarray,
    pose: np.ndarray,
    grip_t: np.ndarray,
    gripper: np.ndarray,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pose (Q, 7) and gripper (Q,) at those of `times_ns` (Q0,) inside both sample spans.

    Returns (kept mask (Q0,), pose, gripper): xyz and gripper linear, quaternion by slerp.
    """
    keep = (times_ns >= max(pose_t[0], grip_t[0])) & (times_ns <= min(pose_t[-1], grip_t[-1]))  # (Q0,)
    t = times_ns[keep]
    xyz = interpolate_linear(pose_t, pose[:, :3], t)  # (Q, 3)
    quat = slerp(pose_t, pose[:, 3:], t)  # (Q, 4)
    return keep, np.concatenate([xyz, quat], axis=1), interpolate_linear(grip_t, gripper, t)


def frame_coverage(table: MotionTable, frame_times_ns: np.ndarray, keep: np.ndarray, source: Path | None) -> str:
    """When the frames and the motion do not span the same time (a video cut short, or longer than the CSV): a
    warning naming the files and what is not used, and the note for the metadata ("" when they match)."""
    t0, period = int(table.timestamps_ns[0]), float(np.median(np.diff(frame_times_ns)))
    motion_end, frames_end = int(table.timestamps_ns[-1]), int(frame_times_ns[-1])
    unused_rows = int((table.timestamps_ns > frames_end + period).sum()) + int(
        (table.timestamps_ns < frame_times_ns[0] - period).sum()
    )
    dropped = int((~keep).sum())
    if not unused_rows and not dropped:
        return ""
    span = (
        f"frames {(frame_times_ns[0] - t0) / NS_PER_S:.3f}-{(frames_end - t0) / NS_PER_S:.3f} s, motion 0.000-"
        f"{(motion_end - t0) / NS_PER_S:.3f} s (from the first CSV row)"
    )
    what = source or table.path.parent
    if unused_rows:
        log.warning(
            "%s: the frames end before the motion does (%s): %d CSV rows of %s without a frame are not used "
            "(assumed: the video was cut short; check it, or --frame-offset-ms)",
            what,
            span,
            unused_rows,
            table.path,
        )
    if dropped:
        log.warning(
            "%s: %d of %d frames lie outside the CSV's time span (%s) and are dropped (assumed: the camera ran "
            "longer than the motion was recorded)",
            what,
            dropped,
            len(keep),
            span,
        )
    return f"{span}; {unused_rows} CSV rows without a frame unused, {dropped} frames without motion dropped"


def demonstration_with_frames(
    episode_id: str,
    table: MotionTable,
    frames: list[bytes],
    frame_times_ns: np.ndarray | None,
    task: str,
    extra: dict[str, str],
    source: Path | None = None,
) -> Demonstration:
    """Frames at `frame_times_ns` (None: one frame per CSV row) with pose/gripper from `table`; `source` names the
    frames (a video) in warnings."""
    extra = {**extra, **table.notes}
    if frame_times_ns is None:
        times, pose, gripper, kept = table.timestamps_ns, table.pose, table.gripper, frames
        extra = {**extra, "frame_times": "one frame per CSV row", "interpolation": "none"}
    else:
        keep, pose, gripper = motion_at(
            frame_times_ns, table.timestamps_ns, table.pose, table.timestamps_ns, table.gripper
        )
        if keep.sum() < 2:
            raise RecordingError(
                f"{table.path}: fewer than 2 frames fall inside the CSV's time span; check --frame-offset-ms"
            )
        coverage = frame_coverage(table, frame_times_ns, keep, source)
        if coverage:
            extra["coverage"] = coverage
        times, kept = frame_times_ns[keep], [f for f, k in zip(frames, keep) if k]
        extra = {**extra, "interpolation": "pose xyz and gripper linear, quaternion slerp, at frame times"}
    return Demonstration(
        episode=Episode(episode_id, fps=median_rate(times), task=task, source=str(table.path.parent), extra=extra),
        timestamps_ns=times,
        pose=pose,
        gripper=gripper,
        frames=kept,
    )


def demonstration_from_csv(
    path: str | os.PathLike, episode_id: str, columns: CsvColumns = CsvColumns(), task: str = ""
) -> Demonstration:
    """A motion-only demonstration: one step per CSV row."""
    table = read_motion_csv(path, columns)
    return Demonstration(
        episode=Episode(
            episode_id,
            fps=median_rate(table.timestamps_ns),
            task=task,
            source=str(table.path),
            extra={"frames": "none", **table.notes},
        ),
        timestamps_ns=table.timestamps_ns,
        pose=table.pose,
        gripper=table.gripper,
    )


def media_of(folder: Path) -> tuple[list[Path], list[Path]]:
    """(videos, numbered images) directly in `folder`."""
    videos = sorted(f for f in folder.iterdir() if f.is_file() and f.suffix.lower() in VIDEO_SUFFIXES)
    return videos, numbered_images(folder)


def demonstration_from_folder(
    folder: str | os.PathLike,
    episode_id: str,
    columns: CsvColumns = CsvColumns(),
    timing: FrameTiming = FrameTiming(),
    task: str = "",
) -> Demonstration:
    """A demonstration from a folder with one CSV and either one video or numbered image files."""
    d = Path(folder)
    csvs = sorted(f for f in d.iterdir() if f.is_file() and f.suffix.lower() == ".csv")
    if len(csvs) != 1:
        raise RecordingError(
            f"{d}: a folder with frames needs exactly one CSV of pose and gripper values, found {len(csvs)}"
        )
    table = read_motion_csv(csvs[0], columns)
    videos, images = media_of(d)
    first = int(table.timestamps_ns[0])
    if videos:
        if len(videos) > 1 or images:
            raise RecordingError(
                f"{d}: give one video or numbered images per folder, found {len(videos)} videos and "
                f"{len(images)} images"
            )
        frames, video_fps = read_video(videos[0])
        if len(frames) < 2:
            raise RecordingError(
                f"{videos[0]}: the video has {len(frames)} readable frame; a demonstration needs at "
                f"least 2 (give the whole video)"
            )
        times, how = timing.times_ns(len(frames), first, timing.frame_rate or video_fps)
        extra = {"frame_source": videos[0].name, "frame_times": how}
        return demonstration_with_frames(episode_id, table, frames, times, task, extra, videos[0])
    frames = read_images(images)
    extra = {"frame_source": f"{len(images)} numbered images"}
    if len(frames) == len(table.timestamps_ns) and timing.frame_rate is None:
        return demonstration_with_frames(episode_id, table, frames, None, task, extra)
    if timing.frame_rate is None:
        raise RecordingError(
            f"{d}: {len(frames)} images for {len(table.timestamps_ns)} CSV rows; "
            "give the camera rate with --frame-rate HZ "
            "(or one image per CSV row)"
        )
    times, extra["frame_times"] = timing.times_ns(len(frames), first, timing.frame_rate)
    return demonstration_with_frames(episode_id, table, frames, times, task, extra)
