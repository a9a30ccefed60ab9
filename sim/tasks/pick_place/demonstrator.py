"""The scripted demonstrator of the pick-and-place task: to the bar, grasp it, carry it to a free place it fits,
put it down, leave; with natural variation.

A demonstration (`PickDraw`, drawn by `draw_pick` from a generator and the scene) has a place (one of the grasp's
free places, drawn uniformly: the scene decides where one is taken and leaves the choice where both are free), a
number of steps per phase (its speed: one pace within the scene's PHASE_STEPS' ranges for the whole motion, so each
stage comes at about the same share of every demonstration), the grasp point along the bar, the place point on the
mat and the carrying height. Its waypoints (`pick_path`) are the actions (8,): xyz, the quaternion xyzw (the
grasp's yaw, turned during the approach) and the gripper command (FINGER_OPEN open, 0 closed); each phase moves
with a minimum-jerk timing. `demonstrations` drives the environment with them, as a robot records a demonstration.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from cnep.runtime import STATE_KEY
from cnep.sim.task import Demonstration, demonstration_seed, recorded
from cnep.sim.tasks.pick_place import scene as P
from cnep.sim.tasks.pick_place.env import PickPlaceEnv, grasp_places, yaw_quaternion


@dataclass(frozen=True)
class PickDraw:
    """One demonstration's choices: place (index of PLACES), steps per phase (PHASE_STEPS' order), grasp (m along
    the bar from its centre), target (x, y) offset on the mat (m), carry_z (m)."""

    place: int
    steps: tuple[int, ...]
    grasp: float
    target: tuple[float, float]
    carry_z: float


def draw_pick(rng: np.random.Generator, orientation: str, taken: list[bool]) -> PickDraw:
    """A demonstration's choices from `rng` for a bar lying `orientation` and the places `taken`."""
    free = [i for i in grasp_places(orientation) if not taken[i]]
    return PickDraw(
        place=free[int(rng.integers(len(free)))],
        steps=phase_steps(float(rng.uniform())),
        grasp=float(rng.uniform(-P.GRASP_OFFSET, P.GRASP_OFFSET)),
        target=tuple(float(v) for v in rng.uniform(-P.PLACE_OFFSET, P.PLACE_OFFSET, 2)),
        carry_z=float(P.CARRY_Z + rng.uniform(-P.CARRY_JITTER, P.CARRY_JITTER)),
    )


def phase_steps(pace: float) -> tuple[int, ...]:
    """The steps of each phase (PHASE_STEPS' order) of a demonstrator whose `pace` in [0, 1] runs from the quickest
    (0) to the slowest (1): one pace for the whole motion, so each stage comes at the same share of every
    demonstration, as a demonstrator's tempo carries through a motion."""
    return tuple(int(round(lo + pace * (hi - lo))) for lo, hi in P.PHASE_STEPS.values())


def pick_path(draw: PickDraw, start: np.ndarray, object_xy: np.ndarray, object_yaw: float) -> np.ndarray:
    """The waypoints (sum of draw.steps, 8) after the gripper's `start` (x, y, z): waypoint k is the action at step
    k; `object_xy` (m) and `object_yaw` (degrees) the bar's pose."""
    orientation_yaw = P.ORIENTATIONS[P.PLACES[draw.place][2]]
    grasp_xy = np.asarray(object_xy) + draw.grasp * _along(object_yaw)
    place_xy = np.asarray(P.PLACES[draw.place][1]) + draw.target + draw.grasp * _along(orientation_yaw)
    up, down = draw.carry_z, P.GRASP_Z
    open_, closed = P.FINGER_OPEN, 0.0
    # Each phase: where it ends (xyz), the yaw at its end, the gripper command during it.
    phases = [
        ((*grasp_xy, up), object_yaw, open_),
        ((*grasp_xy, down), object_yaw, open_),
        ((*grasp_xy, down), object_yaw, closed),
        ((*grasp_xy, up), object_yaw, closed),
        ((*place_xy, up), orientation_yaw, closed),
        ((*place_xy, down + 0.003), orientation_yaw, closed),
        ((*place_xy, down + 0.003), orientation_yaw, open_),
        ((*place_xy, up), orientation_yaw, open_),
    ]
    rows, xyz, yaw = [], np.asarray(start, np.float64), 0.0
    for (end, end_yaw, grip), n in zip(phases, draw.steps):
        tau = np.arange(1, n + 1) / n
        s = 10 * tau**3 - 15 * tau**4 + 6 * tau**5  # minimum-jerk progress, 0 -> 1
        for progress in s:
            point = xyz + progress * (np.asarray(end) - xyz)
            rows.append([*point, *yaw_quaternion(yaw + progress * (end_yaw - yaw)), grip])
        xyz, yaw = np.asarray(end, np.float64), end_yaw
    return np.asarray(rows)


def _along(yaw_deg: float) -> np.ndarray:
    """The long side (2,) of a bar turned `yaw_deg` degrees."""
    return np.array([-np.sin(np.radians(yaw_deg)), np.cos(np.radians(yaw_deg))])


def demonstrations(n: int, seed: int) -> Iterator[Demonstration]:
    """`n` demonstrations drawn with `seed`, each driving the environment from its own reset: the scene drawn decided or
    free, the place chosen in it (its name the behaviour); clean when the bar ended on a valid place."""
    rng = np.random.default_rng(seed)
    env = PickPlaceEnv()
    try:
        for i in range(n):
            observation, info = env.reset(seed=demonstration_seed(seed, i))
            scene = env.scene
            draw = draw_pick(rng, scene["orientation"], scene["taken"])
            steps = [observation]
            for action in pick_path(draw, observation[STATE_KEY][:3], scene["object_xy"], scene["object_yaw"]):
                observation, _, _, _, info = env.step(action.astype(np.float32))
                steps.append(observation)
            yield recorded(steps, env.image_key, P.PLACES[draw.place][0], bool(info["is_success"]))
    finally:
        env.close()
