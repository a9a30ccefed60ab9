"""Demonstrations held at their last step where their recording stops as the gripper changes.

A recording often stops the moment its task is done: the frame in which the gripper lets go of the object is its
last. The model learns each step at its phase (step / (steps - 1)), so that change is one value at phase 1 beside a
run of the other state just before it; the likelihood averages the one value away, and the policy never makes the
change: it carries the object to its place and holds it there. A demonstration whose gripper's last state (open or
closed, as the two-state command reads it: runtime.gripper) lasts fewer than END_HOLD_SHARE of its steps is
trained as if its recording had run on with nothing moving, held at its last step until that state has lasted that
share. A demonstration whose gripper never changes, or whose last state lasts that long already, is trained as it
is. config.json's `files` give each held demonstration's `held_steps`, and the time base counts them (a robot's
seconds map to the phases the model learnt).
"""

from __future__ import annotations

import math

import numpy as np

from cnep.pipeline.train.packed import PackedColumns
from cnep.pipeline.train.parallel import Processes, gather
from cnep.pipeline.train.presets import TrainingColumns
from cnep.recordings.constants import BLOCK_GRIPPER
from cnep.runtime.gripper import GripperCommand

END_HOLD_SHARE = 0.1  # of a demonstration's steps: how long its gripper's last state lasts at least, held if not


def held_steps(gripper: np.ndarray, command: GripperCommand) -> int:
    """The steps to hold a demonstration of gripper values `gripper` (T,) (the recordings' unit) at its last step: as
    many as its gripper's last state (`command`'s nearest value) falls short of END_HOLD_SHARE of its steps, 0 where
    the state never changes."""
    states = np.array([command.nearest(float(v)) for v in np.asarray(gripper).reshape(-1)])
    changed = np.flatnonzero(states != states[-1]) if len(states) else np.empty(0, dtype=np.int64)
    if not len(changed):
        return 0
    lasting = len(states) - 1 - int(changed[-1])  # steps of the last state
    return max(0, math.ceil(END_HOLD_SHARE * len(states)) - lasting)


def end_holds(
    packed: PackedColumns, layout: TrainingColumns, command: GripperCommand | None, procs: Processes
) -> dict[int, int]:
    """Training-set index -> the steps to hold that demonstration at its last step (`held_steps`), of every file
    held, gathered from the ranks' packs (a file not in it is not held; none is where the model has no gripper
    column). All ranks must call this."""
    span = layout.blocks.get(BLOCK_GRIPPER)
    mine = packed.columns(packed.indices, span) if span is not None and command is not None else {}
    holds = {i: held_steps(values[:, 0], command) for i, values in mine.items()}
    return {i: steps for part in gather(procs, holds) for i, steps in part.items() if steps}
