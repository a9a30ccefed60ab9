"""Checks that a demonstration holds what it seems to, whatever it was read from: no value far outside the rest
of its recording (`validation.check_outliers`), and frames of one size.

    demo = checked(demo, "recordings/a.csv")   # refuses an outlier; notes frames that change size

A refusal is one RecordingError naming the source, the step and the value; what is accepted with an assumption
is logged as a warning and noted in the episode metadata (`extra`), so the file says what was assumed.
"""

from __future__ import annotations

import logging
from dataclasses import replace

import numpy as np

from cnep.recordings.records import Demonstration
from cnep.recordings.validation import check_outliers, jpeg_size

log = logging.getLogger(__name__)


def step_labels(timestamps_ns: np.ndarray) -> list[str]:
    """`step i (t = X s)` for each step, the time counted from the first step."""
    seconds = (timestamps_ns - timestamps_ns[0]) / 1e9
    return [f"step {i} (t = {t:.3f} s)" for i, t in enumerate(seconds.tolist())]


def frame_sizes_note(frames: list[bytes] | None, where: str) -> str:
    """ "" when every frame has one size; else a warning and the note: each size and the steps that have it."""
    if not frames:
        return ""
    sizes = [jpeg_size(f) for f in frames]
    distinct = sorted(set(sizes), key=sizes.index)
    if len(distinct) <= 1:
        return ""
    parts = []
    for size in distinct:
        steps = [i for i, s in enumerate(sizes) if s == size]
        name = f"{size[0]}x{size[1]}" if size else "unknown size"
        parts.append(f"{name} at {len(steps)} step(s) from step {steps[0]}")
    note = "; ".join(parts)
    log.warning(
        "%s: the frames change size (%s); each is resized to the network's input, so the features shift where the "
        "size changes (assumed: one camera, rescaled)",
        where,
        note,
    )
    return note


def checked(demo: Demonstration, where: str) -> Demonstration:
    """`demo` after the checks of this module: an outlier is refused, frames of several sizes are noted."""
    check_outliers(demo.pose, demo.gripper, where, step_labels(demo.timestamps_ns))
    note = frame_sizes_note(demo.frames, where)
    if note:
        demo.episode = replace(demo.episode, extra={**demo.episode.extra, "frame_sizes": note})
    return demo
