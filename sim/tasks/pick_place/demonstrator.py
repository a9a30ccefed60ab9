"""The scripted demonstrator of the pick-and-place task: to the bar, grasp it, carry it to a free place it fits,
put it down, leave; with natural variation.

A demonstration (`PickDraw`, drawn by `draw_pick` from a generator and the scene) has a place (one of the grasp's
free places, drawn uniformly: the scene decides where one is taken and leaves the choice where both are free), a
number of steps per phase (its speed: one pace within the scene's PHASE_STEPS' ranges for the whole motion, so each
stage comes at about the same share of every demonstration; in v1 each phase's pace drawn apart), the grasp point
along the bar, the place point on the mat and the carrying height. Its waypoints (`pick_path`) are the actions (8,):
xyz, the quaternion xyzw (the grasp's yaw, turned during the approach) and the gripper command (FINGER_OPEN open, 0
closed); each phase moves with a minimum-jerk timing, lengthened where a robot's limits need (sim.controller).
`PickExpert` is the demonstrator in closed loop: when the place it heads for is taken during the motion, it carries
the bar on to the place valid then. `demonstrations` drives the environment with them as a robot records a
demonstration, each the way its task gives (a `Drive`): v0 the path open loop to its end (follow_path), v1
`PickExpert` to the episode's end (expert_to_episode_end), another layout's to its plan's end (expert_to_plan_end).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator
from dataclasses import dataclass, replace

import numpy as np

from cnep.runtime import STATE_KEY
from cnep.sim.paths import Plan, rollout, through
from cnep.sim.robot import TELEPORT, RobotSettings
from cnep.sim.task import Demonstration, demonstration_seed, recorded
from cnep.sim.tasks.pick_place import scene as P
from cnep.sim.tasks.pick_place.env import PickPlaceEnv
from cnep.sim.tasks.pick_place.layout import PickLayout

CARRY = list(P.PHASE_STEPS).index("carry")  # the phase from which a demonstrator heads for its place


@dataclass(frozen=True)
class PickDraw:
    """One demonstration's choices: place (index of PLACES), steps per phase (PHASE_STEPS' order), grasp (m along
    the bar from its centre), target (x, y) offset on the mat (m), carry_z (m)."""

    place: int
    steps: tuple[int, ...]
    grasp: float
    target: tuple[float, float]
    carry_z: float


def draw_pick(
    rng: np.random.Generator,
    orientation: str,
    taken: list[bool],
    pace_per_phase: bool = False,
    layout: PickLayout = P.BAR,
) -> PickDraw:
    """A demonstration's choices from `rng` for a bar lying `orientation` and the places `taken` of `layout`;
    `pace_per_phase`: each phase's steps drawn apart within PHASE_STEPS (v1), else one pace for the whole motion
    (phase_steps)."""
    free = [i for i in layout.grasp_places(orientation) if not taken[i]]
    place = free[int(rng.integers(len(free)))]
    if pace_per_phase:
        steps = tuple(int(rng.integers(lo, hi + 1)) for lo, hi in P.PHASE_STEPS.values())
    else:
        steps = phase_steps(float(rng.uniform()))
    return PickDraw(
        place=place,
        steps=steps,
        grasp=float(rng.uniform(-layout.grasp_offset, layout.grasp_offset)),
        target=tuple(float(v) for v in rng.uniform(-P.PLACE_OFFSET, P.PLACE_OFFSET, 2)),
        carry_z=float(P.CARRY_Z + rng.uniform(-P.CARRY_JITTER, P.CARRY_JITTER)),
    )


def phase_steps(pace: float) -> tuple[int, ...]:
    """The steps of each phase (PHASE_STEPS' order) of a demonstrator whose `pace` in [0, 1] runs from the quickest
    (0) to the slowest (1): one pace for the whole motion, so each stage comes at the same share of every
    demonstration, as a demonstrator's tempo carries through a motion."""
    return tuple(int(round(lo + pace * (hi - lo))) for lo, hi in P.PHASE_STEPS.values())


def pick_path(
    draw: PickDraw,
    start: np.ndarray,
    object_xy: np.ndarray,
    object_yaw: float,
    robot: RobotSettings = TELEPORT,
    layout: PickLayout = P.BAR,
) -> np.ndarray:
    """The waypoints (steps, 8) after the gripper's `start` (x, y, z): waypoint k is the action at step k;
    `object_xy` (m) and `object_yaw` (degrees) the bar's pose in `layout`; each phase takes draw.steps' steps, or more
    where `robot`'s limits need them (sim.controller.min_jerk_steps)."""
    phases = _phases(draw, object_xy, object_yaw, layout)
    return through(phases, draw.steps, np.asarray(start, np.float64), 0.0, robot)


def _phases(draw: PickDraw, object_xy: np.ndarray, object_yaw: float, layout: PickLayout) -> list[tuple]:
    """The phases of `draw` (PHASE_STEPS' order) in `layout`, each where it ends (xyz, m), the yaw at its end
    (degrees) and the gripper command during it."""
    _, place, orientation = layout.places[draw.place]
    orientation_yaw = layout.orientations[orientation]
    grasp_xy = np.asarray(object_xy) + draw.grasp * _along(object_yaw)
    place_xy = np.asarray(place) + draw.target + draw.grasp * _along(orientation_yaw)
    up, down = draw.carry_z, P.GRASP_Z
    open_, closed = P.FINGER_OPEN, 0.0
    return [
        ((*grasp_xy, up), object_yaw, open_),
        ((*grasp_xy, down), object_yaw, open_),
        ((*grasp_xy, down), object_yaw, closed),
        ((*grasp_xy, up), object_yaw, closed),
        ((*place_xy, up), orientation_yaw, closed),
        ((*place_xy, down + 0.003), orientation_yaw, closed),
        ((*place_xy, down + 0.003), orientation_yaw, open_),
        ((*place_xy, up), orientation_yaw, open_),
    ]


class PickExpert:
    """The scripted demonstrator in closed loop: the path of `draw` (pick_path) from the reset's `start` (x, y, z) in
    the environment's `scene` (PickPlaceEnv.scene) within `robot`'s limits; when the place it heads for is taken
    during the motion (the changed scene), the path to the place valid then: before the bar is lifted its own path's
    rest, after, a new path from its last waypoint on (carry, lower, open, leave); `layout` the scene's."""

    def __init__(
        self,
        draw: PickDraw,
        start: np.ndarray,
        scene: dict,
        robot: RobotSettings = TELEPORT,
        layout: PickLayout = P.BAR,
    ) -> None:
        self.draw, self.start, self.scene, self.robot = draw, np.asarray(start, np.float64), scene, robot
        self.layout = layout
        self.plan = Plan(self._path())

    def action(self, info: dict) -> np.ndarray:
        """The action (8,) float32 after `info` (the reset's, then each step's)."""
        valid, last = info.get("valid_after_change") or [], self.plan.last()
        if valid and self.draw.place not in valid and last is not None:
            self.draw = replace(self.draw, place=valid[0])
            if not info["lifted"]:  # the path so far is the new one's too
                self.plan.replan(self._path()[self.plan.given :])
            else:
                yaw = math.degrees(2 * math.atan2(last[5], last[6]))  # the quaternion xyzw's turn about z
                # The phases from the carry on, to the new place: they do not depend on where the bar lay.
                phases = _phases(self.draw, np.zeros(2), 0.0, self.layout)[CARRY:]
                self.plan.replan(through(phases, self.draw.steps[CARRY:], last[:3], yaw, self.robot))
        return self.plan.next()

    def _path(self) -> np.ndarray:
        scene = self.scene
        return pick_path(self.draw, self.start, scene["object_xy"], scene["object_yaw"], self.robot, self.layout)


def pick_expert(env: PickPlaceEnv, info: dict, rng: np.random.Generator) -> PickExpert:
    """The scripted demonstrator of `env` just reset (its reset's `info`), its choices drawn from `rng` (draw_pick) as
    the environment's version has them, within its robot's limits."""
    version, scene = env.version, env.scene
    draw = draw_pick(rng, scene["orientation"], scene["taken"], version.pace_per_phase, env.layout)
    return PickExpert(draw, np.array([*info["start"], version.start[2]]), scene, version.robot, env.layout)


def _along(yaw_deg: float) -> np.ndarray:
    """The long side (2,) of a bar turned `yaw_deg` degrees."""
    return np.array([-np.sin(np.radians(yaw_deg)), np.cos(np.radians(yaw_deg))])


Drive = Callable[[PickPlaceEnv, dict, np.random.Generator, list[dict]], tuple[dict, int]]


def demonstrations(n: int, seed: int, make_env: Callable[[], PickPlaceEnv], drive: Drive) -> Iterator[Demonstration]:
    """`n` demonstrations drawn with `seed` in the environment `make_env()` makes, each from its own reset (its scene
    drawn decided or free), driven by `drive` (follow_path, expert_to_episode_end or expert_to_plan_end), the states
    and frames as the robot sensed them: the place it chose its behaviour (the layout's name of it); clean when the
    object ended on a valid place."""
    rng = np.random.default_rng(seed)
    env = make_env()
    try:
        for i in range(n):
            observation, info = env.reset(seed=demonstration_seed(seed, i))
            steps = [observation]
            info, place = drive(env, info, rng, steps)
            yield recorded(steps, env.image_key, env.layout.names[place], bool(info["is_success"]))
    finally:
        env.close()


def follow_path(env: PickPlaceEnv, info: dict, rng: np.random.Generator, steps: list[dict]) -> tuple[dict, int]:
    """A `Drive` (v0's): the path of choices drawn from `rng` (pick_path, one pace) from the sensed start (`steps`'
    first state) to its end, open loop, each observation appended to `steps`; the last info and the place chosen."""
    scene = env.scene
    draw = draw_pick(rng, scene["orientation"], scene["taken"])
    for action in pick_path(draw, steps[0][STATE_KEY][:3], scene["object_xy"], scene["object_yaw"]):
        observation, _, _, _, info = env.step(action.astype(np.float32))
        steps.append(observation)
    return info, draw.place


def expert_to_episode_end(
    env: PickPlaceEnv, info: dict, rng: np.random.Generator, steps: list[dict]
) -> tuple[dict, int]:
    """A `Drive` (v1's): the scripted demonstrator in closed loop (pick_expert) until the episode ends, each
    observation appended to `steps`; the last info and the place chosen."""
    expert = pick_expert(env, info, rng)
    info, _ = rollout(env, expert.action, info, steps)
    return info, expert.draw.place


def expert_to_plan_end(env: PickPlaceEnv, info: dict, rng: np.random.Generator, steps: list[dict]) -> tuple[dict, int]:
    """A `Drive` (another layout's, sim.tasks.pick_place.variant): the scripted demonstrator in closed loop
    (pick_expert) until its plan runs out (the episode's step limit at most), each observation appended to `steps`;
    the last info and the place chosen."""
    expert, truncated = pick_expert(env, info, rng), False
    while expert.plan.given < len(expert.plan.waypoints) and not truncated:
        observation, _, _, truncated, info = env.step(expert.action(info))
        steps.append(observation)
    return info, expert.draw.place
