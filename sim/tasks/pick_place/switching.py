"""Whether a policy's switch after the table changed counts: the first switch of the active expert after the change
whose new plan ends on a place valid after the change (`counted_switch`), where the plan's end is the mat its last
waypoint stands over (`plan_place`). A switch to the expert of a place still taken, or of no place, does not count.
An expert may cover more than one place, its decoder choosing between them from the latest frames: the first read
after the change whose plan ends on a valid place, by a switch or within the expert, is when the policy re-routed
(`rerouted`).
"""

from __future__ import annotations

import numpy as np

from cnep.sim.tasks.pick_place import scene as P
from cnep.sim.tasks.pick_place.layout import PickLayout


def plan_place(plan: np.ndarray, layout: PickLayout = P.BAR) -> int | None:
    """The place (index of `layout`'s places) whose mat holds the xy of `plan`'s last waypoint (plan (W, >= 2), m), or
    None."""
    end = np.asarray(plan, np.float64)[-1, :2]
    for i, (_, xy, _) in enumerate(layout.places):
        if np.all(np.abs(end - xy) <= layout.place_half(i)):
            return i
    return None


def counted_switch(
    experts: np.ndarray,
    predicted: np.ndarray,
    change_step: int | None,
    valid_after: list[int] | None,
    layout: PickLayout = P.BAR,
) -> int | None:
    """The first step after the change at which the active expert changed to one whose plan ends on a valid place.

    experts (reads,): the active expert at each read of the policy (a read per step); predicted (reads, W, >= 2): each
    read's waypoints (m); change_step: the step before whose action the table changed (None: it did not; the policy
    first sees it at the read of step change_step + 1); valid_after: the places valid after the change (indices of
    `layout`'s places). None without a change or such a switch.
    """
    if change_step is None or not valid_after:
        return None
    for step in range(change_step + 1, len(experts)):
        if experts[step] != experts[step - 1] and plan_place(predicted[step], layout) in valid_after:
            return step
    return None


def rerouted(
    predicted: np.ndarray, change_step: int | None, valid_after: list[int] | None, layout: PickLayout = P.BAR
) -> int | None:
    """The first step after the change whose read's plan ends on a place valid after it, whichever expert made it
    (the arguments as counted_switch's). None without a change or such a read."""
    if change_step is None or not valid_after:
        return None
    for step in range(change_step + 1, len(predicted)):
        if plan_place(predicted[step], layout) in valid_after:
            return step
    return None
