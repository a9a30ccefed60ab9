"""Whether a policy's switch after the cue showed counts: the first switch of the active expert after the cue whose
new plan passes the box on the cue's side (`counted_switch`), the side a path passes read where it comes nearest the
box's y (`side_of`).
"""

from __future__ import annotations

import numpy as np


def side_of(path: np.ndarray, box_xy: np.ndarray) -> str:
    """Where a path (n, >= 2) of xy (m) passes the box at `box_xy` (2,): "left" (x below the box's, facing the goal)
    or "right", at the point nearest the box's y."""
    path = np.asarray(path, np.float64)
    nearest = int(np.abs(path[:, 1] - box_xy[1]).argmin())
    return "left" if path[nearest, 0] < box_xy[0] else "right"


def counted_switch(
    experts: np.ndarray, predicted: np.ndarray, cue_step: int | None, cue_side: str | None, box_xy: np.ndarray
) -> int | None:
    """The first step after the cue showed at which the active expert changed to one whose plan passes the box on
    the cue's side.

    experts (reads,): the active expert at each read of the policy (a read per step); predicted (reads, W, >= 2): each
    read's waypoints (m); cue_step: the step before whose action the cue showed (None: it did not; the policy first
    sees it at the read of step cue_step + 1); cue_side: the side it shows; box_xy (2,): where the box stands (m).
    None without a cue or such a switch.
    """
    if cue_step is None or cue_side is None:
        return None
    for step in range(cue_step + 1, len(experts)):
        if experts[step] != experts[step - 1] and side_of(predicted[step], box_xy) == cue_side:
            return step
    return None
